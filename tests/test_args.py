"""The CLI's one argument layer: frame, view, point and pair grammars, negative values, one-line errors."""

from __future__ import annotations

import pytest

from lfusd.camera import parse_frames, parse_view
from lfusd.cli import build_parser
from lfusd.errors import LfusdError


@pytest.mark.parametrize("text,frames", [
    ("7", [7]),
    ("1-3", [1, 2, 3]),
    ("1-5,8", [1, 2, 3, 4, 5, 8]),
    (" 8, 2-3 ,3", [2, 3, 8]),  # sorted, each frame once
    ("4-4", [4]),
    ("-3", [-3]),  # time codes may be negative
    ("-2-1", [-2, -1, 0, 1]),
    ("-5--4,0", [-5, -4, 0]),
])
def test_frame_grammar(text, frames):
    assert parse_frames(text) == frames


@pytest.mark.parametrize("text,needle", [
    ("5-1", "range 5-1 is reversed"),
    ("1-", "not N, A-B"),
    ("a", "not N, A-B"),
    ("1,,2", "not N, A-B"),
    ("1-2-3", "not N, A-B"),
    ("--3", "not N, A-B"),
    ("-1--3", "range -1--3 is reversed"),
])
def test_frame_grammar_refuses_on_one_line(text, needle):
    with pytest.raises(LfusdError, match=needle) as e:
        parse_frames(text)
    assert "\n" not in str(e.value)


def test_view_grammar_takes_comma_and_underscore():
    assert parse_view("4,4") == (4, 4) and parse_view("0_12") == (0, 12) and parse_view(" 2 , 3 ") == (2, 3)
    for bad in ("4", "4,4,4", "a,b", "-1,2", "4;4"):
        with pytest.raises(LfusdError, match="ROW,COL or ROW_COL"):
            parse_view(bad)


def parse(*argv):
    return build_parser().parse_args([str(a) for a in argv])


def test_commands_share_the_grammars():
    a = parse("verify", "OUT", "--frames", "1-5,8", "--views", "0,0", "4_4", "--threshold", "flow_fwd=0.1")
    assert a.frames == [1, 2, 3, 4, 5, 8] and a.views == [(0, 0), (4, 4)] and a.threshold == [("flow_fwd", 0.1)]
    a = parse("derive", "OUT", "--frames", "2", "--views", "1_2")
    assert a.frames == [2] and a.views == [(1, 2)]
    assert parse("export", "pfm", "OUT", "DEST", "--view", "3_4").view == (3, 4)
    assert parse("render-video", "S.usda", "-o", "O", "--frames", "3-5", "--resolution", "64x48").frames == (3, 5)
    a = parse("stage", "new", "street", "-o", "s.usda", "--grid", "3x5", "--resolution", "64X48")
    assert (a.grid, a.resolution) == ((3, 5), (64, 48))


def test_negative_values_are_values_for_every_command():
    a = parse("rig", "add", "s.usda", "--at", "-0.05,0.6,3", "--look-at", "-1,-2,0.5", "--baseline", "-.5")
    assert a.at == (-0.05, 0.6, 3.0) and a.look_at == (-1.0, -2.0, 0.5) and a.baseline == -0.5
    a = parse("animate", "add-person", "s.usda", "--path", "-3,2", "-1.5,-2", "4,-0.5", "--speed", "-1")
    assert a.path == ["-3,2", "-1.5,-2", "4,-0.5"] and a.speed == -1.0


@pytest.mark.parametrize("argv,needles", [
    (["verify", "OUT", "--frames", "5-1"], ["argument --frames", "range 5-1 is reversed"]),
    (["render-video", "S.usda", "-o", "O", "--frames", "1-5,8"], ["--frames", "not one contiguous range A-B"]),
    (["render-video", "S.usda", "-o", "O", "--frames", "3-2"], ["--frames", "A-B"]),
    (["derive", "OUT", "--views", "4"], ["argument --views", "ROW,COL"]),
    (["export", "pfm", "OUT", "DEST", "--view", "x"], ["argument --view", "ROW,COL"]),
    (["verify", "OUT", "--threshold", "depth"], ["--threshold", "not KEY=NUMBER"]),
    (["stage", "new", "street", "-o", "s.usda", "--grid", "0x3"], ["--grid", "positive"]),
    (["rig", "add", "s.usda", "--look-at", "-1,-2"], ["--look-at", "X,Y,Z"]),
    (["render", "S.usda", "-o", "O", "--light", "sun"], ["argument --light", "'auto', 'none'"]),
    (["render-video", "S.usda", "-o", "O", "--light", "on"], ["argument --light", "'auto', 'none'"]),
])
def test_bad_values_are_one_line_usage_errors(capsys, argv, needles):
    from support.cli import assert_one_line_error, run_cli

    code, _, err = run_cli(capsys, *argv)
    assert code == 2
    assert_one_line_error(code, err, *needles)


def test_render_commands_take_light_auto_by_default():
    for command in ("render", "render-video"):
        assert parse(command, "S.usda", "-o", "O").light == "auto"
        assert parse(command, "S.usda", "-o", "O", "--light", "none").light == "none"
