"""The command line refuses a bad number before anything starts: argparse's exit 2 naming the option
and the reason (`companion.contracts.arguments`), never a traceback or a run of nothing."""

from __future__ import annotations

import argparse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.cli.main import build_parser, main
from companion.contracts import arguments
from companion.contracts.mission import MAX_STEPS

MC = ["mc", "--mission", "m.toml"]
GEN = ["generate", "--count", "1", "--seed", "1", "--out", "o"]
NUMBER_TYPES = {
    arguments.count,
    arguments.step_count,
    arguments.natural,
    arguments.port,
    arguments.positive,
    arguments.weight,
    arguments.fraction,
}


def _options(parser: argparse.ArgumentParser):
    """(command, option) for every option of every subcommand, with its argparse action."""
    for action in parser._actions:  # argparse has no public walk of its tree
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                for command, option in _options(sub):
                    yield (f"{name} {command}".strip(), option)
        else:
            yield ("", action)


def test_every_numeric_option_has_a_bounded_type() -> None:
    bare = [(c, o.option_strings) for c, o in _options(build_parser()) if o.type in (int, float)]
    assert not bare, f"options typed int or float, which take any value: {bare}"
    typed = {o.type for _, o in _options(build_parser()) if o.type in NUMBER_TYPES}
    assert typed == NUMBER_TYPES


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([*MC, "--runs", "0"], "argument --runs: must be >= 1, got 0"),
        ([*MC, "--steps", "0"], f"argument --steps: must be in 1..{MAX_STEPS}, got 0"),
        ([*MC, "--seed", "-1"], "argument --seed: must be >= 0, got -1"),
        ([*MC, "--workers", "0"], "argument --workers: must be >= 1, got 0"),
        ([*MC, "--runs", "2.5"], "argument --runs: not a whole number: '2.5'"),
        (["soak", "--loss", "2"], "argument --loss: must be in [0, 1], got 2"),
        (["run", "m.toml", "--speedup", "-1"], "argument --speedup: must be > 0, got -1"),
        (["run", "m.toml", "--speedup", "nan"], "argument --speedup: must be finite, got nan"),
        (["run", "m.toml", "--view-port", "70000"], "argument --view-port: must be in 0..65535, got 70000"),
        (["tune", "--budget", "5", "--uncertainty-weight", "-0.1"], "must be >= 0, got -0.1"),
        (["view", "--port", "-5"], "argument --port: must be in 0..65535, got -5"),
        ([*GEN, "--uavs", "0-3"], "argument --uavs: must be LOW-HIGH with 1 <= LOW <= HIGH <= 64, got 0-3"),
        ([*GEN, "--across", "900-800"], "argument --across: must be LOW-HIGH with 1 <= LOW <= HIGH"),
        ([*GEN, "--targets", "abc"], "argument --targets: not a range LOW-HIGH or a single value: 'abc'"),
        ([*GEN, "--modes", "grid,x"], "argument --modes: unknown 'x'; choose from grid, continuous"),
    ],
)
def test_a_bad_number_is_refused_naming_the_option(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


@given(st.integers(min_value=-(10**6), max_value=10**7))
def test_whole_number_types_accept_exactly_their_range(value: int) -> None:
    for kind, low, high in (
        (arguments.count, 1, None),
        (arguments.natural, 0, None),
        (arguments.step_count, 1, MAX_STEPS),
        (arguments.port, 0, 65535),
    ):
        inside = value >= low and (high is None or value <= high)
        if inside:
            assert kind(str(value)) == value
        else:
            with pytest.raises(argparse.ArgumentTypeError):
                kind(str(value))


@given(st.integers(min_value=-5, max_value=70), st.integers(min_value=-5, max_value=70))
def test_a_whole_span_is_low_high_within_its_bounds(low: int, high: int) -> None:
    span = arguments.whole_span(1, 64)
    if 1 <= low <= high <= 64:
        assert span(f"{low}-{high}") == (low, high)
        assert span(str(low)) == (low, low)
    elif low >= 0 and high >= 0:  # a minus sign would read as the separator
        with pytest.raises(argparse.ArgumentTypeError):
            span(f"{low}-{high}")


def test_the_family_options_reach_the_generator_as_ranges() -> None:
    args = build_parser().parse_args([*GEN, "--uavs", "3-5", "--across", "900", "--modes", "continuous"])
    assert (args.uavs, args.across, args.modes) == ((3, 5), (900.0, 900.0), ("continuous",))
    assert (args.targets, args.layouts) == ((5, 20), ("edge", "clustered"))  # the defaults, parsed


def test_an_output_folder_that_cannot_be_made_is_an_error_not_a_traceback(tmp_path, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert main([*GEN[:-1], str(blocker / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Not a directory" in err and str(blocker) in err, err
