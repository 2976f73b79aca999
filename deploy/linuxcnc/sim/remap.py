# The simulated lathe's remaps: LinuxCNC's own index_lathe_tool_with_wear (T<tool><wear>) and
# ignore_m6, from its stdglue (configs/sim/axis/remap, Debian's linuxcnc-uspace).
from stdglue import *  # noqa: F403
