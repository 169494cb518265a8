"""Verdicts: a result judged by rules, each with its value, thresholds, level and a sentence that says what it
means. One rule for every report (camera calibration, projector calibration): numpy-free and OpenCV-free, so the
API can judge a stored result's numbers when it shows them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

VERDICT_LEVELS = ("good", "check", "bad")
YES_NO = "yes/no"  # the unit of a check that holds or does not (value 1 or 0)


@dataclass(frozen=True)
class VerdictCheck:
    """One rule of the verdict: the value, its thresholds and the level it earned."""

    name: str
    value: float
    unit: str
    good_limit: float
    bad_limit: float
    higher_is_better: bool
    level: str
    message: str


@dataclass(frozen=True)
class Verdict:
    """good / check / bad: the worst level of the checks, with the reasons for anything not good."""

    level: str
    reasons: tuple[str, ...]
    checks: tuple[VerdictCheck, ...]


def check(
    name: str, value: float, unit: str, *, good: float, bad: float, higher_is_better: bool = False, what: str
) -> VerdictCheck:
    """A rule: `value` is good within `good`, bad beyond `bad`, to be checked between; NaN is bad (not measured)."""
    if value != value:  # NaN: nothing to judge by, which a person must look at
        return VerdictCheck(name, value, unit, good, bad, higher_is_better, "bad", f"{what}: not measured")
    if higher_is_better:
        level = "good" if value >= good else ("check" if value >= bad else "bad")
        limits = f"good ≥ {good:g} {unit}, bad < {bad:g} {unit}"
    else:
        level = "good" if value <= good else ("check" if value <= bad else "bad")
        limits = f"good ≤ {good:g} {unit}, bad > {bad:g} {unit}"
    message = f"{what}: {value:.4g} {unit} ({limits})".replace(" )", ")")
    if unit == YES_NO:
        message = f"{what}: {'yes' if value >= good else 'no'}"
    return VerdictCheck(name, float(value), unit, good, bad, higher_is_better, level, message)


def verdict_of(checks: Sequence[VerdictCheck]) -> Verdict:
    """The worst level of the checks, and the message of each check that is not good."""
    level = max((c.level for c in checks), key=VERDICT_LEVELS.index)
    reasons = tuple(c.message for c in checks if c.level != "good") or ("all checks within their thresholds",)
    return Verdict(level=level, reasons=reasons, checks=tuple(checks))
