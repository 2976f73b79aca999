"""What the part program reads back: each feature's result in the part under way, the part's
verdict once every feature is measured, and the answer to its "feature measured" request.

The request: the CNC names a feature and a new request sequence number; the feature is the
one named until the answer (a diameter the job recognises as another feature's is refused
meanwhile, not taken as the one named). The gauge answers that number once it has
``measurements`` good measurements of the feature from frames taken after the request (the
verdict is the part's fused value of the feature against its tolerance), or, when
``answer_within_s`` passes first, as refused, with the reason of the last measurement it
could not use (``REFUSALS``). A program waits for the answer with a timeout of its own longer
than ``answer_within_s``: past it, the gauge itself is away (its heartbeat says so).

Pure: measurements, requests and time in (seconds, one clock); answers out.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from service.compensation.job import Job
from service.quality.parts import FeatureResult, PartRecord

NONE, IN, OUT, REFUSED = 0, 1, 2, 3
"""A feature's verdict (and a request's answer): none yet in this part, in tolerance, out of
it, refused (its reason code says why)."""
UNDER_WAY, INCOMPLETE = 0, 3
"""The part's verdict besides ``IN`` and ``OUT``: a feature of it not measured yet, or the part
ended without one."""


@dataclass(frozen=True)
class Refusal:
    """A reason code the gauge answers a request with when it could not measure."""

    code: int
    name: str
    means: str
    action: str


REFUSALS: tuple[Refusal, ...] = (
    Refusal(1, "nothing_measured", "no measurement came in time: no part under the laser, "
            "or the camera is away", "check the part is in place and the gauge's status; "
            "request again or stop"),
    Refusal(2, "no_stripe", "no laser line on the part", "check the laser is on and the "
            "feature is under it"),
    Refusal(3, "too_few_points", "too little of the line to fit", "clean the part (coolant, "
            "chips); check the feature is under the laser"),
    Refusal(4, "arc_too_short", "the line covers too little of the circumference",
            "check the feature is under the laser, not its edge"),
    Refusal(5, "fit_failed", "the line does not fit a circle", "clean the part; a shoulder "
            "under the laser: move to the feature's middle"),
    Refusal(6, "uncertain", "the diameter is more uncertain than the gauge may answer for",
            "clean the part (coolant, chips, a film) and request again"),
    Refusal(7, "bad_image", "an image the gauge cannot use (over-exposed, blank)",
            "check the camera's view and the light"),
    Refusal(8, "not_concentric", "the part runs off the spindle axis", "check the clamping"),
    Refusal(9, "no_feature", "the diameter fits none of the job's features", "name the "
            "feature in the request; check the job in force"),
    Refusal(10, "other_feature", "the diameter under the laser is another feature's than the "
            "one asked for", "check the program moved to the feature it names before it "
            "asked"),
)
BY_NAME: dict[str, Refusal] = {r.name: r for r in REFUSALS}


def feature_verdict(result: FeatureResult | None) -> int:
    """``IN``, ``OUT`` or ``NONE`` (not measured in this part yet)."""
    if result is None or result.diameter_mm is None:
        return NONE
    return IN if result.verdict == "ok" else OUT


def part_verdict(part: PartRecord | None, finished: bool) -> int:
    """``IN`` or ``OUT`` once every feature is measured (``OUT`` as soon as one is out),
    ``UNDER_WAY`` until then, ``INCOMPLETE`` for a part that ended without one."""
    if part is None:
        return UNDER_WAY
    if part.verdict == "out":
        return OUT
    if part.verdict == "ok":
        return IN
    return INCOMPLETE if finished else UNDER_WAY


@dataclass(frozen=True)
class Answer:
    """The answer to request ``seq`` for ``feature``: ``reason`` 0 when measured (the verdict
    is the feature's result in the part), else the ``Refusal`` code."""

    seq: int
    feature: int
    reason: int


@dataclass
class MeasureHandshake:
    """The "feature measured" handshake's state (see the module's docstring)."""

    measurements: int = 3
    answer_within_s: float = 5.0
    _seq: int = 0
    _feature: int = 0
    _since_s: float = 0.0
    _good: int = 0
    _refusal: int = 1
    _open: bool = False

    def request(self, seq: int, feature: int, now_s: float) -> bool:
        """The CNC's request (written again every cycle by some clients: only a new sequence
        number or feature opens one); True when it opened one, or, for ``seq`` 0 (no
        request), when it dropped one waiting or forgot the last number (so that a program
        started again may begin its numbers again)."""
        if seq == 0:
            dropped = self._open or self._seq != 0
            self._seq, self._open = 0, False
            return dropped
        if (seq, feature) == (self._seq, self._feature):
            return False
        self._seq, self._feature, self._since_s = seq, feature, now_s
        self._good, self._refusal, self._open = 0, BY_NAME["nothing_measured"].code, True
        return True

    @property
    def open(self) -> bool:
        """A request waits for its answer."""
        return self._open

    def measured(self, feature: int | None, refusal: str, taken_s: float, now_s: float
                 ) -> Answer | None:
        """A measurement published, of a frame taken at ``taken_s``: a good one of
        ``feature`` (``refusal`` empty), or one refused (``refusal`` a ``REFUSALS`` name:
        its status, ``no_feature``, ``other_feature``); the answer when it completes the
        request."""
        if not self._open:
            return None
        if taken_s < self._since_s:
            return self.tick(now_s)
        if not refusal and feature == self._feature:
            self._good += 1
            if self._good >= self.measurements:
                return self._answer(0)
        elif refusal:
            found = BY_NAME.get(refusal)
            self._refusal = found.code if found else BY_NAME["nothing_measured"].code
        return self.tick(now_s)

    def tick(self, now_s: float) -> Answer | None:
        """The answer when the request has waited ``answer_within_s``: refused."""
        if self._open and now_s - self._since_s >= self.answer_within_s:
            return self._answer(self._refusal)
        return None

    def _answer(self, reason: int) -> Answer:
        self._open = False
        return Answer(self._seq, self._feature, reason)


@dataclass(frozen=True)
class Results:
    """What the part program reads back now: the part under way (or, with nothing of one
    measured yet, the last one, ``finished``) and its number, the features answered refused
    and not measured since (reason codes), and the last answer with the feature's result
    then."""

    job: Job | None
    part: PartRecord | None
    number: int
    finished: bool
    refused: dict[int, int] = field(default_factory=dict)
    answer: Answer | None = None
    answered: FeatureResult | None = None


@dataclass
class PartResults:
    """What the part program reads back, kept from one measurement to the next: the
    handshake, whether a request names the feature (and what was named before it), the
    features answered refused, the last answer, the last part finished.

    The handshake's steps are atomic (``measured`` in the thread that publishes measurements,
    ``request`` and ``tick`` in another): a request is answered once, whoever answers it."""

    handshake: MeasureHandshake = field(default_factory=MeasureHandshake)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    naming: bool = False
    """A request waiting names the feature (``request``)."""
    named_before: int | None = None
    refused: dict[int, int] = field(default_factory=dict)
    answer: Answer | None = None
    answered: FeatureResult | None = None
    last_part: PartRecord | None = None

    def request(self, seq: int, feature: int, now_s: float, named: int | None
                ) -> tuple[bool, int | None]:
        """A request (``named`` the feature named now): whether anything changed, and the
        feature to be named from now on. A request opened names its feature until it is
        answered; ``seq`` 0 drops one waiting (the feature named before it is named again)
        and clears the last answer (``measured_seq`` reads 0)."""
        with self._lock:
            opened = self.handshake.request(seq, feature, now_s)
        if not opened:
            return False, named
        if seq == 0:
            self.answer = self.answered = None
            naming, self.naming = self.naming, False
            return True, self.named_before if naming else named
        if not self.naming:
            self.named_before = named
        self.naming = True
        return True, feature

    def another_features(self, job: Job, named: int, diameter_mm: float) -> str:
        """Why ``diameter_mm`` is not the feature ``named`` while a request names it: the job
        recognises it as another feature's ("" when it does not)."""
        other = job.recognise(diameter_mm).feature if self.naming else None
        if other is None or other.number == named:
            return ""
        return (f"{diameter_mm:.4f} mm is feature {other.number}'s ({other.name}), not "
                f"feature {named}'s, which the CNC asked to measure")

    def measured(self, feature: int | None, good: bool, status: str, taken_s: float,
                 now_s: float) -> Answer | None:
        """A measurement published (``good``: taken into the part as ``feature``'s), of a
        frame taken at ``taken_s``: the answer when it ends the request waiting. One refused
        is so by its status, or as a good diameter of no feature (of another feature's than
        the one a request names)."""
        if good and feature is not None:
            self.refused.pop(feature, None)
        refusal = "" if good else status if status != "ok" else \
            "other_feature" if self.naming else "no_feature"
        with self._lock:
            return self.handshake.measured(feature, refusal, taken_s, now_s)

    def tick(self, now_s: float) -> Answer | None:
        """The answer to a request that waited its time out (``MeasureHandshake.tick``)."""
        with self._lock:
            return self.handshake.tick(now_s)

    def answered_with(self, answer: Answer, part: PartRecord | None) -> bool:
        """``answer`` given, with ``part`` the part under way; True when the request named
        the feature (``named_before`` is to be named again)."""
        self.answered = next((f for f in part.features if f.feature == answer.feature),
                             None) if part is not None else None
        if answer.reason:
            self.refused[answer.feature] = answer.reason
        self.answer = answer
        naming, self.naming = self.naming, False
        return naming

    def finished(self, part: PartRecord) -> None:
        """A part finished."""
        self.last_part = part
        self.refused.clear()

    def now(self, job: Job | None, under_way: PartRecord | None, number: int) -> Results:
        """What the part program reads back with ``under_way`` the part under way."""
        part = under_way or self.last_part
        return Results(job, part, number if under_way or part is None else part.number,
                       under_way is None, dict(self.refused), self.answer, self.answered)


def markdown_table() -> str:
    """The reason codes as the register map's table (``docs/modbus-register-map.md`` holds
    it; a test checks it)."""
    rows = ["| code | name | means | what to do |", "|---:|---|---|---|"]
    rows += [f"| {r.code} | `{r.name}` | {r.means} | {r.action} |" for r in REFUSALS]
    return "\n".join(rows) + "\n"
