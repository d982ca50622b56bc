"""The `cec` command line: the demo writes its GIF, render writes PNG/GIF, bad input fails cleanly."""

from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

from apps.cli import main
from cec.envs import overcooked as oc


def test_demo_writes_one_gif_with_every_classic_kitchen(tmp_path: Path) -> None:
    out = tmp_path / "demo.gif"
    assert main(["demo", "--out", str(out), "--steps", "5"]) == 0
    with Image.open(out) as gif:
        width, height = gif.size
    # five kitchens side by side, 32 px per cell, 8 px apart; the tallest kitchens have 5 rows
    widths = [int(oc.classic_level(n).size[1]) for n in oc.CLASSIC_ASCII]
    assert width == 32 * sum(widths) + 8 * 4
    assert height == 32 * 5


def test_render_png_and_gif_from_an_ascii_file(tmp_path: Path) -> None:
    kitchen = tmp_path / "k.txt"
    kitchen.write_text("WWPWW\nO0 1O\nW   W\nWBWXW\n")
    png, gif = tmp_path / "k.png", tmp_path / "k.gif"
    assert main(["render", str(kitchen), "--png", str(png), "--gif", str(gif), "--steps", "3"]) == 0
    with Image.open(png) as im:
        assert im.size == (5 * 64, 4 * 64)  # 64 px per cell: a readable picture by default
    assert gif.stat().st_size > 0


def test_render_takes_any_kitchen_and_its_help_says_so(tmp_path: Path, capsys) -> None:
    """Not only the classic ones: a held-out kitchen's name and `generated:SEED` render as well."""
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    helptext = " ".join(capsys.readouterr().out.split())
    assert "any kitchen" in helptext and "generated:SEED" in helptext and "ASCII kitchen file" in helptext
    for name in ("generated_006", "generated:7"):
        png = tmp_path / f"{name.replace(':', '_')}.png"
        assert main(["render", name, "--png", str(png)]) == 0
        assert png.stat().st_size > 0


def test_render_rejects_a_malformed_kitchen(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    kitchen = tmp_path / "bad.txt"
    kitchen.write_text("WWPWW\nO0 1Q\nW   W\nWBWXW\n")
    assert main(["render", str(kitchen), "--png", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "unknown character 'Q' at row 1, column 4" in err
    assert not (tmp_path / "x.png").exists()


def test_render_rejects_an_unknown_layout(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["render", "no_such_kitchen", "--png", "x.png"]) == 2
    assert "unknown Overcooked level 'no_such_kitchen'; use a classic kitchen" in capsys.readouterr().err


def test_levels_sample_writes_a_contact_sheet_and_ascii(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "levels.png"
    assert main(["levels", "sample", "--n", "6", "--columns", "3", "--out", str(out), "--ascii"]) == 0
    with Image.open(out) as im:
        assert im.size[0] > 3 * 5 * 24  # three kitchens per row, at least 5 cells wide each
    kitchens = capsys.readouterr().out.split("\n\n")
    assert len(kitchens) == 6


def test_levels_sample_rejects_an_impossible_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["levels", "sample", "--n", "2", "pots=[0, 1]"]) == 2
    assert "1 <= min <= max" in capsys.readouterr().err


def test_levels_validate_reports_solvability_and_reasons(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    split = tmp_path / "split.txt"
    split.write_text("WWWWW\nO0B1P\nW X W\nWWWWW\n")
    assert main(["levels", "validate", str(split)]) == 1
    assert "NOT solvable" in capsys.readouterr().out
    assert main(["levels", "validate", "coord_ring"]) == 0
    out = capsys.readouterr().out
    assert "solvable" in out and "held-out evaluation kitchen 'coord_ring'" in out
    bad = tmp_path / "bad.txt"
    bad.write_text("WWPWW\nO0  O\nW   W\nWBWXW\n")
    assert main(["levels", "validate", str(bad)]) == 2
    binary = tmp_path / "kitchen.png"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xd0\xff")
    assert main(["levels", "validate", str(binary)]) == 2
    assert "is not a text file" in capsys.readouterr().err
    huge = tmp_path / "huge.txt"
    huge.write_text("W" * 100_000)
    assert main(["levels", "validate", str(huge)]) == 2
    assert "an ASCII kitchen is a few lines of tiles" in capsys.readouterr().err


def test_overrides_may_follow_flags_and_max_updates_must_be_positive(capsys):
    from apps.cli import build_parser, parse_args

    parser = build_parser()
    args = parse_args(parser, ["train", "--config", "x.yaml", "--quiet", "num_envs=8", "seed=2"])
    assert args.overrides == ["num_envs=8", "seed=2"] and args.quiet
    args = parse_args(parser, ["train", "num_envs=4", "--config", "x.yaml", "seed=3"])
    assert args.overrides == ["num_envs=4", "seed=3"]
    for argv, message in (
        (["train", "--max-updates", "-1"], "must be a positive integer, got -1"),
        (["train", "--max-updates", "0"], "must be a positive integer, got 0"),
        (["train", "--config", "x.yaml", "--bogus", "num_envs=8"], "unrecognized arguments: --bogus"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            parse_args(parser, argv)
        assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_the_core_commands_run_without_the_services_packages() -> None:
    """A GPU box with the `cec` core only (no Ray, Redis, gRPC health/reflection or web stack): the CLI
    starts, core commands run, and a service's command names the missing package instead of a traceback."""
    import subprocess
    import sys

    blocked = ["ray", "redis", "starlette", "uvicorn", "websockets", "grpc_health", "grpc_reflection"]
    script = (
        "import sys\n"
        f"for m in {blocked!r}: sys.modules[m] = None\n"
        "from apps.cli import main\n"
        "assert main(['layouts']) == 0\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    for command in (["up"], ["play", "serve"], ["evaluator"], ["level-server"]):
        out = subprocess.run(
            [sys.executable, "-c", script, *command], capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 2, (command, out.stderr[-2000:])
        assert "needs the package" in out.stderr and "pip install" in out.stderr, out.stderr[-2000:]
        assert "Traceback" not in out.stderr


def test_every_command_reports_a_config_error_the_same_way(capsys: pytest.CaptureFixture[str]) -> None:
    """One override syntax (trailing KEY=VALUE) and one error line for a bad one, in the library's commands
    and in the services' alike: `cec <command>: config error: ...`, exit status 2."""
    assert main(["train", "--config", "configs/train/quick_cpu.yaml", "num_envz=8"]) == 2
    assert capsys.readouterr().err.startswith("cec train: config error: unknown key 'num_envz'")
    assert main(["level-server", "prot=1"]) == 2
    assert capsys.readouterr().err.startswith("cec level-server: config error: unknown key 'prot'")
    assert main(["render", "cramped_room", "max_stepz=3", "--png", "/tmp/unused.png"]) == 2
    assert capsys.readouterr().err.startswith("cec render: config error: unknown key 'max_stepz'")
