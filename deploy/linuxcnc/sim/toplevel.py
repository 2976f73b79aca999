# LinuxCNC's embedded Python for the simulated lathe: the remaps in remap.py.
import remap  # noqa: F401
