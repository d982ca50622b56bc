"""One entry point for every service: `cec <command>` and `python -m services.<package>` parse their
arguments, log, load the config and turn errors into exit statuses the same way.

A service module defines its `add_arguments(parser)` and `run(args) -> int` and one `SERVICE = Service(...)`;
`SERVICE.register` adds it to the `cec` command (apps/cli.py's one registration list) and `SERVICE.main` is
its `python -m` entry. `run` raises rather than prints:

- bad input, a `ValueError` (`ConfigError`: a bad preset, override, zoo manifest or study file; a bad
  level or record) or a `CheckpointError`: one line `cec <command>: config error: ...` (`error:` for the
  others) on stderr, exit status 2;
- one of the service's `failures` (by default `OSError`: a port taken; the evaluator adds `StoreError`:
  Redis unreachable): one line `cec <command>: error: ...`, exit status 1;
- `AlreadyDone` (what was asked is done already: a finished run started or resumed again): its message as
  one line `cec <command>: ...`, exit status 0.

Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cec.checkpoints import CheckpointError
from cec.config import ConfigError, load_config

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def configure_logging(verbose: bool = False) -> None:
    """INFO (DEBUG when `verbose`) to stderr, in the one format every service and the `cec` command use."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=LOG_FORMAT)


def override_arguments(parser: argparse.ArgumentParser, example: str, what: str = "config") -> None:
    """Trailing `KEY=VALUE` overrides (`args.overrides`): the one override syntax of every command (also
    after flags: `apps.cli.parse_args` takes them there too)."""
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help=f"{what} overrides, e.g. {example}")


def config_arguments(parser: argparse.ArgumentParser, preset: str, example: str) -> None:
    """`--config YAML` and trailing `KEY=VALUE` overrides (read by `load_service_config`)."""
    parser.add_argument("--config", help=f"YAML preset (e.g. {preset}); defaults if omitted")
    override_arguments(parser, example)


def load_service_config(cls: type, args: argparse.Namespace) -> Any:
    """The config of `config_arguments`' flags: the preset (or the defaults) with the overrides applied;
    `ConfigError` naming the field and the fix."""
    return load_config(cls, args.config, args.overrides)


class AlreadyDone(ConfigError):  # noqa: N818 - not an error: exit status 0
    """What a command was asked to do is done already (a finished run): said as such, not as an error, and
    exit status 0 (`run_reporting`); a `ConfigError` to callers that only refuse what they cannot do."""


#: What bad input raises anywhere (a `LevelError` is a `ValueError`): exit status 2.
INPUT_ERRORS: tuple[type[BaseException], ...] = (ValueError, CheckpointError)


def report_error(command: str, err: BaseException) -> None:
    """The one line an error of `cec <command>` prints: `config error:` for a config, `error:` otherwise."""
    kind = "config error" if isinstance(err, ConfigError) else "error"
    print(f"cec {command}: {kind}: {err}", file=sys.stderr)


def run_reporting(
    command: str, fn: Callable[[], int], failures: tuple[type[BaseException], ...] = (OSError,)
) -> int:
    """`fn()`'s exit status, or its error as one line (`report_error`) and 2 for bad input, 1 for one of
    `failures` (the work could not be done here: a port taken, Redis unreachable); 0 with its message for
    `AlreadyDone`."""
    try:
        return fn()
    except AlreadyDone as done:
        print(f"cec {command}: {done}", file=sys.stderr)
        return 0
    except INPUT_ERRORS as err:
        report_error(command, err)
        return 2
    except failures as err:
        report_error(command, err)
        return 1


@dataclass(frozen=True)
class Service:
    """A service's command line.

    Attributes:
        command: its `cec` subcommand, e.g. "level-server".
        module: the module `python -m` runs it as, e.g. "services.level_server".
        help: one line for `cec --help`.
        add_arguments: adds its flags to a parser.
        run: runs it on parsed arguments; returns the exit status.
        failures: exception types that mean "the service could not do its work here" (exit 1).
    """

    command: str
    module: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    failures: tuple[type[BaseException], ...] = (OSError,)

    def register(self, sub: Any) -> None:
        """Adds `cec <command>` to the `cec` command's subparsers."""
        parser = sub.add_parser(self.command, help=self.help, description=self.help)
        self.add_arguments(parser)
        parser.set_defaults(func=self.call)

    def call(self, args: argparse.Namespace) -> int:
        """`run(args)` with its errors as one line on stderr and an exit status (module docstring)."""
        return run_reporting(self.command, lambda: int(self.run(args)), self.failures)

    def main(self, argv: list[str] | None = None) -> int:
        """`python -m <module> ...`: the same as `cec <command> ...`."""
        parser = argparse.ArgumentParser(prog=f"python -m {self.module}", description=self.help)
        self.add_arguments(parser)
        args = parser.parse_args(argv)
        configure_logging()
        return self.call(args)
