"""Generates the Python gRPC stubs (and their .pyi type stubs) from `proto/`, the one source of truth.

    python scripts/gen_proto.py          # (re)write the generated files next to the package code
    python scripts/gen_proto.py --check  # exit 1 if the committed files differ from a fresh generation

Needs the `dev` extra (grpcio-tools for protoc and its Python/gRPC plugins, mypy-protobuf for the gRPC
.pyi stubs). `tests/unit/levels/test_level_wire.py` runs `--check`, so stale stubs fail the test suite.
"""

from __future__ import annotations

import argparse
import filecmp
import shutil
import sys
import sysconfig
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROTO_ROOT = ROOT / "proto"


def _plugin(name: str) -> str:
    path = Path(sysconfig.get_path("scripts")) / name
    if not path.exists():
        found = shutil.which(name)
        if found is None:
            sys.exit(f"{name} not found; install the dev extra: pip install -e '.[dev]'")
        return found
    return str(path)


def protos() -> list[Path]:
    return sorted(PROTO_ROOT.rglob("*.proto"))


def generate(out: Path) -> list[Path]:
    """Runs protoc on every .proto file into `out`; returns the generated files relative to `out`."""
    try:
        from grpc_tools import protoc
    except ImportError:
        sys.exit("grpcio-tools is not installed; install the dev extra: pip install -e '.[dev]'")
    import grpc_tools

    include = Path(grpc_tools.__file__).parent / "_proto"  # google/protobuf/*.proto
    files = [str(p.relative_to(PROTO_ROOT)) for p in protos()]
    args = [
        "protoc",
        f"-I{PROTO_ROOT}",
        f"-I{include}",
        f"--python_out={out}",
        f"--pyi_out={out}",
        f"--grpc_python_out={out}",
        f"--plugin=protoc-gen-mypy_grpc={_plugin('protoc-gen-mypy_grpc')}",
        f"--mypy_grpc_out={out}",
        *files,
    ]
    if protoc.main(args) != 0:
        sys.exit("protoc failed (see the message above)")
    return sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="fail if the committed stubs are stale")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        generated = generate(out)
        stale = [str(rel) for rel in generated if not (ROOT / rel).exists() or not filecmp.cmp(
            out / rel, ROOT / rel, shallow=False)]  # fmt: skip
        if args.check:
            if stale:
                print("stale generated gRPC stubs: " + ", ".join(stale), file=sys.stderr)
                print("regenerate them with: python scripts/gen_proto.py", file=sys.stderr)
                return 1
            print(f"{len(generated)} generated files are up to date with proto/")
            return 0
        for rel in generated:
            (ROOT / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(out / rel, ROOT / rel)
        print(f"wrote {len(generated)} files: " + ", ".join(map(str, generated)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
