"""Every reason code the compensation can give in its decision log, with what it means, who
acts on it and how: the operator's runbook table (``docs/runbooks.md`` holds
``markdown_table()``; a test checks it, and that every code the controller and the runtime
can give is here).

Codes built from another name: ``status_<status>`` (a measurement refused for its status:
each measurement status, and ``status_held_for_<hold>`` for each hold), ``gate_<state>``
(nothing judged in that state).
"""

from __future__ import annotations

from dataclasses import dataclass

NOBODY, OPERATOR, TECHNICIAN, INTEGRATOR = "nobody", "operator", "technician", "integrator"
"""Who acts: nobody (the gauge goes on by itself), the operator at the machine, the technician
(calibration, master, settings), the integrator (the CNC's program and its registers)."""


@dataclass(frozen=True)
class Reason:
    """A reason code: ``means`` in the operator's words, ``who`` acts, ``action`` how."""

    code: str
    means: str
    who: str
    action: str


REASONS: tuple[Reason, ...] = (
    # What the loop does when all is well.
    Reason("write", "an offset is sent to the CNC", NOBODY, "nothing"),
    Reason("applied", "the CNC acknowledged the offset", NOBODY, "nothing"),
    Reason("proposed", "an offset is proposed, not written: shadow mode, or writes blocked "
           "(a master check or gauge study due or failed: the reason says which)", TECHNICIAN,
           "switch shadow mode off when the loop is to steer; for a block, do what it names"),
    Reason("deadband", "the process is where it should be: nothing to correct", NOBODY,
           "nothing"),
    Reason("below_resolution", "the correction is smaller than the CNC's offset resolution",
           NOBODY, "nothing"),
    Reason("baseline", "the CNC's total wear offset is the reference of the cumulative limit",
           NOBODY, "nothing"),
    Reason("settings", "the compensation settings were changed (who and what are logged)",
           NOBODY, "nothing; check the change was meant"),
    Reason("other_settings", "settings that do not move the law were changed", NOBODY,
           "nothing"),
    Reason("insert_change", "a person recorded an insert change (the tool's wear offset zeroed "
           "at the CNC): compensation starts again from the new insert's parts", NOBODY,
           "nothing; zero the wear offset at the CNC before or right after recording it"),
    Reason("dead_time_measured", "the gauge measured the dead time from its own offsets; "
           "when it differs from the typed one, the law now waits the measured one",
           INTEGRATOR, "set compensation.dead_time_measurements (or dead_time_s) to it, or "
                       "find what changed in the part program"),
    # The process estimate gathering itself.
    Reason("starting", "the process estimate waits for two measurements that agree", NOBODY,
           "nothing: it starts within a few parts"),
    Reason("set_aside", "one measurement far from the process estimate is set aside until the "
           "next says outlier or step", NOBODY,
           "nothing; if it repeats part after part, check the part and the gauge's view"),
    Reason("dead_time", "waiting out the dead time after an offset (window law)", NOBODY,
           "nothing"),
    Reason("filling_window", "filling the window of measurements (window law)", NOBODY,
           "nothing"),
    Reason("cut_before_reset", "this part was cut before the reset or insert change: it says "
           "nothing of the new insert", NOBODY, "nothing"),
    Reason("features_disagree", "the features of one tool disagree beyond their bound: one "
           "correction cannot hold them all", TECHNICIAN,
           "check the tool and the part (deflection, taper); put a feature on an offset "
           "entry of its own if it keeps disagreeing"),
    # The CNC's side.
    Reason("hand_change", "someone changed the CNC's wear offset at the panel: taken as a "
           "known step, the parts still held to nominal", NOBODY,
           "nothing; the cumulative limit counts the change"),
    Reason("cnc_total_changed", "the CNC's wear offset was set back at the CNC (an insert "
           "change?): the process is estimated again from the parts cut after it", NOBODY,
           "nothing; record insert changes on the dashboard so the log says so"),
    Reason("cnc_total_unknown", "the CNC's total wear offset has not been read yet", NOBODY,
           "nothing at start; if it stays, check the CNC's link (the status says what)"),
    Reason("cnc_total_unreadable", "the CNC's total could not be read just before an offset "
           "went out: the offset was dropped", INTEGRATOR,
           "check the CNC's Modbus link and its total register"),
    Reason("no_baseline", "a reset or enabling came between an offset's decision and its "
           "sending: the offset was dropped", NOBODY, "nothing"),
    Reason("not_in_flight", "an answer for an offset that is not the one in flight was "
           "ignored", INTEGRATOR, "if it repeats, check the CNC's handshake "
                                  "(offset_seq, ack_seq)"),
    Reason("uncertain", "the CNC did not acknowledge an offset in time: compensation holds "
           "until the CNC's registers say whether it was applied; normal when a part cycle "
           "is longer than plc.ack_timeout_s with the pull handshake", INTEGRATOR,
           "size plc.ack_timeout_s to the part cycle; if it stays, check the CNC's "
           "program and link"),
    Reason("not_applied", "the CNC answered that the offset was not applied: it is not sent "
           "again", INTEGRATOR, "check why the CNC refused it (its program's limits)"),
    Reason("limit", "the cumulative offset is at its limit (compensation.max_total_mm), or "
           "the offset would take the CNC's total beyond it", OPERATOR,
           "change or re-measure the tool, then record the insert change or reset"),
    # Alarms and stops.
    Reason("implausible", "a deviation beyond the plausibility limit (a broken tool, a wrong "
           "part or nominal): nothing is written, an alarm is raised", OPERATOR,
           "check the tool and the part; the next plausible measurement ends the alarm, or "
           "acknowledge it on the dashboard"),
    Reason("plausible_again", "a plausible measurement ended the alarm: compensation resumes",
           NOBODY, "nothing"),
    Reason("acknowledged", "a person acknowledged the alarm", NOBODY, "nothing"),
    Reason("no_alarm", "an acknowledgement came with no alarm to acknowledge", NOBODY,
           "nothing"),
    Reason("safe_area", "a deviation beyond the safe area: compensation stopped", OPERATOR,
           "check the machine, the part and the nominal; then reset compensation"),
    Reason("reset", "compensation was reset (who is logged)", NOBODY, "nothing"),
    Reason("reset_refused", "a reset was refused (the reason says why: e.g. the CNC may not "
           "reset through its register)", TECHNICIAN, "reset from the dashboard or the API"),
    Reason("reset_unsettled", "a reset was refused while an offset is in flight", OPERATOR,
           "wait for the CNC to settle the offset, then reset"),
    Reason("no_nominal", "no nominal diameter is set: nothing is judged", TECHNICIAN,
           "put a job in force or set compensation.nominal_mm"),
    # Measurements refused.
    Reason("bad_diameter", "a measurement without a positive finite diameter", NOBODY,
           "nothing; if it repeats, see the measurement status"),
    Reason("bad_uncertainty", "a measurement without a finite uncertainty", NOBODY,
           "nothing; if it repeats, report it: it is a fault of the gauge"),
    Reason("uncertain_measurement", "a measurement more uncertain than allowed "
           "(compensation.max_uncertainty_fraction of the tolerance width)", OPERATOR,
           "clean the window and the part; check the laser line on the live view"),
    Reason("other_calibration", "a measurement made with another calibration than the active "
           "one", NOBODY, "nothing: it passes with the change of calibration"),
    Reason("out_of_order", "a measurement not newer than the last one judged", NOBODY,
           "nothing"),
    Reason("stale", "a measurement older than compensation.max_age_s when it was judged",
           TECHNICIAN, "if it repeats, the host is overloaded: see the status's problems"),
    Reason("future", "a measurement from the future (the clock jumped)", TECHNICIAN,
           "check the host's clock (NTP)"),
    Reason("status_no_stripe", "no laser line in the picture", OPERATOR,
           "check the laser is on and the part is under it"),
    Reason("status_too_few_points", "too little of the laser line was found", OPERATOR,
           "clean the window; check the part is under the line and lit"),
    Reason("status_arc_too_short", "the line covers too short an arc of the shaft", TECHNICIAN,
           "check the camera's and laser's aim at the shaft"),
    Reason("status_fit_failed", "no circle could be fitted to the line", OPERATOR,
           "check the part under the laser (chips, coolant)"),
    Reason("status_uncertain", "the measurement's own uncertainty is too large", OPERATOR,
           "clean the window and the part; check for coolant mist"),
    Reason("status_bad_image", "the picture is unusable (exposure, a broken frame)",
           TECHNICIAN, "check the camera's exposure and its network"),
    Reason("status_not_concentric", "the surface is not concentric with the spindle axis",
           TECHNICIAN, "check the part's clamping and the calibrated axis"),
    Reason("status_held_for_calibration", "the camera is looking at a calibration board",
           NOBODY, "nothing: it ends with the session or after 10 minutes"),
    Reason("status_held_for_master", "the master is being measured", NOBODY,
           "nothing: it ends with the measurement"),
    Reason("status_held_for_gauge_study", "a gauge study is running with the master in the "
           "lathe", NOBODY, "nothing: it ends with the study"),
    Reason("status_held_for_log_unwritable", "the decision log cannot be written: no offset "
           "goes out that could not be logged", TECHNICIAN,
           "free the disk the store is on; the status names it"),
    Reason("status_held_for_runout", "the part runs out beyond spindle.max_tir_mm: its "
           "diameter does not move the tool", OPERATOR, "check the part's clamping"),
    Reason("status_held_for_no_feature", "the diameter fits none of the job's features",
           TECHNICIAN, "check the job in force is the part in the lathe"),
    Reason("gate_pending", "waiting for the CNC to acknowledge the offset in flight", NOBODY,
           "nothing"),
    Reason("gate_uncertain", "an offset was not acknowledged: holding until the CNC's "
           "registers settle it", INTEGRATOR, "as for uncertain"),
    Reason("gate_alarm", "the plausibility alarm holds compensation", OPERATOR,
           "as for implausible"),
    Reason("gate_stopped", "compensation stopped: waiting for a reset", OPERATOR,
           "as for safe_area"),
)


def by_code() -> dict[str, Reason]:
    """The reasons by their code."""
    return {r.code: r for r in REASONS}


def markdown_table() -> str:
    """The reasons as a Markdown table (what ``docs/runbooks.md`` must contain)."""
    lines = ["| code | what it means | who acts | what to do |", "|---|---|---|---|"]
    lines += [f"| `{r.code}` | {r.means} | {r.who} | {r.action} |" for r in REASONS]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown_table(), end="")
