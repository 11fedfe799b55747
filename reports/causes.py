"""Why a time-domain check failed: the catalogue of causes the report names, and the rules that test them.

Every failure of a check (reports/time_domain.py) is a :class:`Failure`: what failed (its ``kind``), its
text, and the evidence where it happened (time, speed, load, the torque command against the limit, the
acceleration before it, whether the I-f start had the loop). :func:`classify` names its cause, one id of
:data:`CATALOGUE`, with the numbers of the case and the change that fixes it (:class:`Named`):

1. the family's own finding first (its report hooks' ``failure_cause``, reports/family.py): causes in
   its own analysis (a PLL's root, an HF injection's coupling band), as catalogue ids;
2. then the shared rules, from the evidence alone (:func:`shared_cause`): a start that never handed
   over is ``not_tested_sensorless``; a rotor that slipped against the I-f current vector is
   ``if_current_below_load`` (the current's torque, at most what the run shows it produced, did not
   carry the load and the acceleration), unless the current already produced the torque limit's and the
   open loop began as a drop back while the drive braked or accelerated at ACCEL_SHARE of its full
   acceleration or more: then ``observer_lag_acceleration`` (the frame starts at the observer's lagging
   speed and no I-f current within the limit catches the rotor; the gimbal motor of docs/examples/motors,
   braking at p (T_max + T_N) / J, 10 times the start's ramp, dropped back 0.11 p.u. off the rotor's
   speed with its tuned gains, 0.20 p.u. with its file's, and slipped; its reference ramped at the
   start's acceleration, it ran through); a drive that
   ended away from its reference is
   ``ramp_slower_than_reference`` where the I-f start's time since the reference's last step made
   the difference (the rest of the step at the torque limit fits the time to the judged end, with the
   start's time added it does not), else ``torque_limit`` where its torque command sat at T_max, else
   ``ramp_slower_than_reference``; a
   position error or loss in closed loop is ``observer_lag_acceleration`` where the drive accelerated
   at ACCEL_SHARE of its full acceleration or more just before, ``rhp_band`` where the drive's
   linearization at that speed and load (the family's ``linearize``) has a right-half-plane pole,
   ``torque_limit`` where the torque command sat at its limit, else ``estimate_error``; a final
   speed-estimation error is ``estimate_error``;
3. in one run (:func:`classify_all`), a failure of the run's end after it lost the rotor (or diverged,
   or slipped in the I-f start) has the cause of that loss.

Shared code names no family here: the family-specific causes are ids a family's hooks return.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Cause:
    """One cause of the catalogue: its id, what it is (a few words) and the change that fixes it."""

    id: str
    title: str
    fix: str


CATALOGUE: dict[str, Cause] = {
    c.id: c
    for c in (
        Cause(
            "torque_limit",
            "torque limit reached",
            "the drive asked more torque than its limit gives: raise the limit ([control] T_max, within the "
            "inverter's current) or ask less (a slower speed ramp, a smaller load)",
        ),
        Cause(
            "if_current_below_load",
            "I-f current below the load's",
            "the open-loop current carried less torque than the load and the start's acceleration need: "
            "raise the I-f current ([startup] current, up to the torque limit's), lower the start's "
            "acceleration ([startup] acceleration) or start against a smaller load",
        ),
        Cause(
            "ramp_slower_than_reference",
            "ramp slower than the reference",
            "the drive's speed followed a slower ramp than its reference asked: give the reference the "
            "time the drive needs (a slower ramp), or a faster start ([startup] acceleration, a lower "
            "handover [startup] w_on: gains tuned for a lower w_min, a shorter [startup] dwell) or speed "
            "loop ([control] alpha_s)",
        ),
        Cause(
            "observer_lag_acceleration",
            "observer lag under acceleration",
            "the observer lagged the rotor while the drive accelerated: a faster observer at those speeds "
            "(sensorless tune over the envelope up to +-T_max), a limited acceleration (a slower speed "
            "ramp or a lower [control] T_max) or a later handover ([startup] w_on)",
        ),
        Cause(
            "pll_root",
            "PLL root",
            "the PLL's slower root is slower than the speed loop closing on it needs: faster PLL gains or "
            "a slower speed loop",
        ),
        Cause(
            "injection_coupling_band",
            "injection coupling band",
            "the HF injection's correction turns sign regenerating in this speed band: keep the drive out "
            "of it under load, or observer gains that keep it stable there (sensorless tune)",
        ),
        Cause(
            "injection_speed_loop",
            "speed loop against the HF injection",
            "the speed loop feeds the carrier's speed-estimate ripple back as a carrier current against the "
            "injection's error signal: a slower speed loop ([control] alpha_s) or a narrower speed filter",
        ),
        Cause(
            "rhp_band",
            "RHP band",
            "the linearized drive has a right-half-plane pole at this speed and load: gains that are stable "
            "there (sensorless tune over an envelope that holds it), or keep the drive out of the band",
        ),
        Cause(
            "sampling_period",
            "sampling period too long for the speed",
            "the sampled drive has no operating point it holds at this speed with its sampling period (its "
            "loss moves up with a shorter period): a shorter sampling period ([control] T_s), or keep the "
            "drive below this speed",
        ),
        Cause(
            "estimate_error",
            "estimate error",
            "the observer's estimate settled off the rotor at steady operation: the motor's parameter "
            "estimates (measure R_s, L and psi_pm closer; state their errors to sensorless tune) or gains "
            "with a smaller steady error there",
        ),
        Cause(
            "speed_unreachable",
            "speed out of the drive's reach",
            "a start-up speed at or above the rated speed or the no-load speed at the DC link: the open "
            "loop never gets there; a handover speed below both ([startup] w_on, the firmware's "
            "open-loop speed) with an observer that holds there",
        ),
        Cause(
            "not_tested_sensorless",
            "not tested sensorless",
            "the observer was not in the loop for the part of the run the check tests: a handover at a "
            "lower speed where the design allows it ([startup] w_on), or a run that reaches the observer's "
            "range",
        ),
    )
}

# the causes of a failure in the open-loop I-f start or its handover, whose remedy is a lower handover
# (gains tuned for a lower w_min), not the observer's transient (reports/tune_proof.py failed_in_the_start)
START_CAUSES = frozenset({"ramp_slower_than_reference", "if_current_below_load", "not_tested_sensorless"})

# what can fail in a check (reports/time_domain.py); the closed-loop ones are judged on the observer
KINDS = ("diverged", "rejected", "lost", "position", "speed_estimate", "tracking", "slip", "no_handover")
CLOSED_LOOP = frozenset({"diverged", "rejected", "lost", "position"})
ACCEL_SHARE = 0.25  # of the drive's full acceleration p T_max / J: "under acceleration" from there
AT_LIMIT = 0.98  # of T_max: the torque command sat at the limit
LOAD_SHARE = 0.95  # of the torque the I-f current produced: the load alone took it


@dataclass(frozen=True)
class Failure:
    """One failed criterion of a check and the evidence where it happened (None: not recorded)."""

    kind: str  # one of KINDS
    text: str
    t: float | None = None  # [s]
    w_pu: float | None = None  # rotor speed there [p.u.]
    w_ref_pu: float | None = None  # speed reference there [p.u.]: where the drive was asked to run
    load_pu: float | None = None  # load torque there [p.u. of T_N]
    torque_e_pu: float | None = None  # electromagnetic torque there [p.u. of T_N] (its sign: motoring or not)
    torque_pu: float | None = None  # peak |torque command| just before (slip: peak |T_e| in open loop) [p.u.]
    limit_pu: float | None = None  # the drive's torque limit T_max [p.u. of T_N]
    accel_share: float | None = None  # mean |dw/dt| just before, over the full acceleration p T_max / J
    open_loop: bool = False  # the I-f start had the loop there
    # a slip whose open-loop run began as a drop back from closed loop: the drive's mean |dw/dt| over the
    # window before it, over p T_max / J, and the rotor's speed less the open-loop frame's there [p.u.]
    drop_accel_share: float | None = None
    drop_speed_err_pu: float | None = None
    # a run's end (tracking): since the reference's last step, the time the I-f start had the loop, the
    # time to the judged tail, and the time the rest of the step needs at the torque limit [s]
    open_s: float | None = None
    avail_s: float | None = None
    need_s: float | None = None

    @property
    def open_loop_took_it(self) -> bool:
        """Whether the I-f start's time made the difference: the step's speed outside the start, at the
        torque limit, fits the time there is; with the start's time added it does not."""
        if self.open_s is None or self.avail_s is None or self.need_s is None or self.open_s <= 0:
            return False
        return self.need_s <= self.avail_s < self.need_s + self.open_s

    @property
    def at_limit(self) -> bool:
        """Whether the torque command sat at the drive's limit."""
        return (
            self.torque_pu is not None
            and self.limit_pu is not None
            and self.torque_pu >= AT_LIMIT * self.limit_pu
        )


@dataclass(frozen=True)
class Named:
    """A failure's cause: its catalogue id and the numbers of this case (with a change more specific
    than the catalogue's, where the finder knows one)."""

    cause: str
    detail: str = ""
    change: str = ""  # the change that fixes this case, where the finder knows it (else the catalogue's)

    def __post_init__(self) -> None:
        if self.cause not in CATALOGUE:
            raise ValueError(f"cause {self.cause!r} is not in the catalogue (reports/causes.py)")

    @property
    def title(self) -> str:
        """What the cause is, in a few words."""
        return CATALOGUE[self.cause].title

    @property
    def fix(self) -> str:
        """The change that fixes it: the finder's for this case, else the catalogue's."""
        return self.change or CATALOGUE[self.cause].fix

    def sentence(self) -> str:
        """One clause for a finding: "cause: title (detail); fix: ..."."""
        detail = f" ({self.detail})" if self.detail else ""
        return f"cause: {self.title}{detail}; fix: {self.fix}"


# (failure) -> Named or None: a family's own finding (reports/family.py ReportHooks.failure_cause, bound to
# its drive and gains) or the shared linearization's right-half-plane test
Finder = Callable[[Failure], "Named | None"]


def _where(f: Failure) -> str:
    parts = []
    if f.w_pu is not None:
        parts.append(f"speed {f.w_pu:+.3g} p.u.")
    if f.load_pu is not None:
        parts.append(f"load {f.load_pu:+.3g} T_N")
    return ", ".join(parts)


def operating_torque_pu(f: Failure) -> float | None:
    """The torque [p.u. of T_N] of a failure's operating point: the electromagnetic torque where
    recorded (braking at the limit while the load pulls the other way is regenerating), else the load."""
    return f.torque_e_pu if f.torque_e_pu is not None else f.load_pu


def shared_cause(f: Failure, unstable: Callable[[Failure], bool | None] = lambda f: None) -> Named:
    """The cause of ``f`` by the shared rules (module docstring); ``unstable(f)``: whether the drive's
    linearization at the failure's speed and load has a right-half-plane pole (None: not known)."""
    if f.kind == "no_handover":
        return Named("not_tested_sensorless", "the open-loop start ran throughout")
    if f.kind == "slip":
        carried = f.torque_pu
        if (
            f.drop_accel_share is not None
            and f.drop_accel_share >= ACCEL_SHARE
            and carried is not None
            and f.limit_pu is not None
            and carried >= AT_LIMIT * f.limit_pu
        ):  # more current cannot help: it gave the torque limit's; the frame started off the rotor
            err = (
                f" with the open-loop frame {f.drop_speed_err_pu:+.3g} p.u. off the rotor's speed"
                if (f.drop_speed_err_pu is not None)
                else ""
            )
            return Named(
                "observer_lag_acceleration",
                f"the drive dropped back to the open-loop start while its speed changed at "
                f"{f.drop_accel_share:.2g} of the full acceleration p T_max / J{err}; the I-f current "
                f"already produced {carried:.3g} T_N, its torque limit's {f.limit_pu:.3g} T_N",
                "the open loop cannot catch a rotor braking at the torque limit: ramp the speed reference "
                "at the start's acceleration ([control] speed_ramp = [startup] acceleration) "
                "or lower [control] T_max, so that the drive drops back at the start's rate; an observer "
                "that holds the full acceleration lower (sensorless tune) lowers w_on",
            )
        if carried is not None and f.load_pu is not None and abs(f.load_pu) >= LOAD_SHARE * carried:
            why = f"load {abs(f.load_pu):.3g} T_N against at most {carried:.3g} T_N the current produced"
        elif carried is not None:
            why = (
                f"at most {carried:.3g} T_N the current produced, less than the load "
                f"{abs(f.load_pu or 0.0):.3g} T_N and the acceleration's torque together"
            )
        else:
            why = "the current's torque did not carry the load and the acceleration"
        return Named("if_current_below_load", why)
    if f.kind == "tracking":
        if f.open_loop_took_it:
            return Named(
                "ramp_slower_than_reference",
                f"in the open-loop start: it had the loop for {1e3 * (f.open_s or 0):.3g} ms of the "
                f"{1e3 * (f.avail_s or 0):.3g} ms after the reference's last step; at the torque limit the "
                f"rest of the step needs {1e3 * (f.need_s or 0):.3g} ms",
            )
        if f.at_limit:
            return Named(
                "torque_limit", f"torque command {f.torque_pu:.3g} T_N at the limit {f.limit_pu:.3g} T_N"
            )
        where = "in the open-loop start (its ramp)" if f.open_loop else "in closed loop (the speed loop)"
        return Named("ramp_slower_than_reference", where)
    if f.kind in CLOSED_LOOP:
        where = _where(f)
        if f.accel_share is not None and f.accel_share >= ACCEL_SHARE:
            return Named(
                "observer_lag_acceleration",
                f"{where}, accelerating at {f.accel_share:.2g} of the full acceleration p T_max / J",
            )
        if unstable(f):
            return Named("rhp_band", f"{where}: the linearized drive has a right-half-plane pole there")
        if f.at_limit:
            return Named("torque_limit", f"{where}, torque command at the limit {f.limit_pu:.3g} T_N")
        return Named("estimate_error", f"{where}, at steady speed")
    return Named("estimate_error", _where(f) or "the run's end")


def classify(
    f: Failure, family: Finder | None = None, unstable: Callable[[Failure], bool | None] = lambda f: None
) -> Named:
    """The cause of ``f``: the family's finding where it has one, else the shared rules."""
    if f.kind not in KINDS:
        raise ValueError(f"failure kind {f.kind!r} is not one of {KINDS}")
    own = family(f) if family is not None else None
    return own if own is not None else shared_cause(f, unstable)


def classify_all(
    failures: list[Failure],
    family: Finder | None = None,
    unstable: Callable[[Failure], bool | None] = lambda f: None,
) -> list[Named]:
    """The cause of each failure of one run: a run that lost the rotor (or diverged, or slipped in the
    I-f start) ends wherever it ends, so a failure of its end (tracking, final speed estimate) has the
    cause of that loss, said so; the others are classified on their own evidence."""
    out = [classify(f, family, unstable) for f in failures]
    first = next((i for i, f in enumerate(failures) if f.kind in {"lost", "diverged", "slip"}), None)
    if first is None:
        return out
    loss, named = failures[first], out[first]
    when = f" at t = {loss.t:.4g} s" if loss.t is not None else ""
    for i, f in enumerate(failures):
        if f.kind in {"tracking", "speed_estimate"}:
            out[i] = Named(
                named.cause,
                f"a consequence of the rotor lost{when}: {named.detail}".rstrip(": "),
                named.change,
            )
    return out
