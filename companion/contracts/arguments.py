"""The command line's number types: argparse refuses a bad number before anything starts.

The error names the option and the reason (`uavsearch mc: error: argument --runs: must be >= 1,
got 0`, exit 2).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence

from companion.contracts.mission import MAX_STEPS


def _integer(text: str, least: int, most: int | None = None) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < least or (most is not None and value > most):
        bound = f">= {least}" if most is None else f"in {least}..{most}"
        raise argparse.ArgumentTypeError(f"must be {bound}, got {value}")
    return value


def _real(text: str, within: Callable[[float], bool], bound: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    if not within(value):
        raise argparse.ArgumentTypeError(f"must be {bound}, got {text}")
    return value


def count(text: str) -> int:
    """A whole number >= 1: runs, missions, workers, days."""
    return _integer(text, 1)


def step_count(text: str) -> int:
    """A run's length in steps: 1 to the mission files' own bound."""
    return _integer(text, 1, MAX_STEPS)


def natural(text: str) -> int:
    """A whole number >= 0: seeds, step and instance indices."""
    return _integer(text, 0)


def port(text: str) -> int:
    """A TCP port, 0 for any free one."""
    return _integer(text, 0, 65535)


def positive(text: str) -> float:
    """A finite real number > 0: a speed-up."""
    return _real(text, lambda v: v > 0, "> 0")


def weight(text: str) -> float:
    """A finite real number >= 0: a term's weight."""
    return _real(text, lambda v: v >= 0, ">= 0")


def fraction(text: str) -> float:
    """A real number in [0, 1]: a probability."""
    return _real(text, lambda v: 0 <= v <= 1, "in [0, 1]")


def sensor_pair(text: str) -> tuple[float, float]:
    """'PD,PF': a probability of detection and a false-alarm rate per look, each in [0, 1]."""
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected PD,PF, two probabilities such as 0.8,0.02: {text!r}")
    return fraction(parts[0].strip()), fraction(parts[1].strip())


def _span(text: str, parse: Callable[[str], float], least: float, most: float) -> tuple[float, float]:
    low, _, high = text.partition("-")
    try:
        lo, hi = parse(low), parse(high or low)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a range LOW-HIGH or a single value: {text!r}") from None
    if not least <= lo <= hi <= most:
        raise argparse.ArgumentTypeError(
            f"must be LOW-HIGH with {least:g} <= LOW <= HIGH <= {most:g}, got {text}"
        )
    return lo, hi


def whole_span(least: int, most: int) -> Callable[[str], tuple[int, int]]:
    """'LOW-HIGH' or 'N' (LOW = HIGH = N): an inclusive range of whole numbers within [least, most]."""

    def parse(text: str) -> tuple[int, int]:
        lo, hi = _span(text, int, least, most)
        return int(lo), int(hi)

    return parse


def real_span(least: float, most: float) -> Callable[[str], tuple[float, float]]:
    """'LOW-HIGH' or 'X': an inclusive range of real numbers within [least, most]."""
    return lambda text: _span(text, float, least, most)


def names(allowed: Sequence[str]) -> Callable[[str], tuple[str, ...]]:
    """'A,B,...': one or more of `allowed`, in the order given."""

    def parse(text: str) -> tuple[str, ...]:
        chosen = tuple(v.strip() for v in text.split(",") if v.strip())
        for v in chosen or ("",):
            if v not in allowed:
                raise argparse.ArgumentTypeError(f"unknown {v!r}; choose from {', '.join(allowed)}")
        return chosen

    return parse


class HelpFormatter(argparse.HelpFormatter):
    """Every option's help with its default, appended as "(default: X)".

    Nothing is appended when the text already says it, or when there is none to say (a flag, a
    required option, a default of None).
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if action.required and "required" not in text:
            return f"{text} (required)"
        if (
            "default" in text
            or action.required
            or default is None
            or default is False
            or default == argparse.SUPPRESS
            or action.nargs == 0  # a flag
            or not (action.option_strings or action.nargs in ("?", "*"))
        ):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, list | tuple) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class _MissionPositional(argparse.Action):
    """The mission as a positional argument, with the same destination as `--mission`.

    A second, different file is an error.
    """

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        if values is None:  # not given: `--mission` or the default stands
            return
        given = getattr(namespace, self.dest, None)
        if given is not None and given != self.default_of_option and str(given) != str(values):
            parser.error(f"the mission is given twice: {given} and {values}")
        setattr(namespace, self.dest, values)

    default_of_option: object = None


def mission_argument(
    parser: argparse.ArgumentParser,
    required: bool = True,
    default: str | None = None,
    type: Callable[[str], object] = str,
    help: str = "the mission file (TOML)",
) -> None:
    """The mission file, given as `FILE` or as `--mission FILE` (one name for every command)."""
    shown = f"default: {default}" if default else ("required" if required else "default: none")
    parser.add_argument(
        "--mission", default=default, type=type, metavar="FILE", help=f"{help}; or FILE ({shown})"
    )
    action = parser.add_argument(
        "mission", nargs="?", default=None, type=type, metavar="FILE", action=_MissionPositional,
        help="the same as --mission FILE",
    )  # fmt: skip
    action.default_of_option = default  # type: ignore[attr-defined]
    parser.set_defaults(mission_required=required)


def check_mission(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Exit with `parser`'s usage when a command that needs a mission was given none."""
    if getattr(args, "mission_required", False) and getattr(args, "mission", None) is None:
        parser.error("a mission file is required: FILE or --mission FILE")
