"""How every command runs: typer and click customised so that help shows values only where
an option takes one, and expected errors (bad input, a full disk, Ctrl-C) are one line with
their exit code; plus the helpers the commands share (`_fail`, `_json`, `_load_config`)."""

from __future__ import annotations

import functools
import importlib
import json
import re
import sys
import warnings
from pathlib import Path
from typing import Annotated, Any

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from tactile_compliance import __version__

#: The exceptions of the click that typer's commands run on: typer vendors its own click
#: (typer._click) in recent versions and used the click package before, so they are found
#: through typer's public BadParameter rather than by importing either.
_click_errors = importlib.import_module(typer.BadParameter.__module__)


#: Exit codes: 0 done; 1 a run failed (cells of a grid, a demo step) or writing failed
#: although the input was fine (a full disk or quota, in every command); 2 bad input (a
#: path, a file's content, a config key, an option), which includes click's usage
#: errors; 130 interrupted (Ctrl-C; re-run to continue).
EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 1, 2, 130


_debug = False  # --debug: let errors raise with their traceback


def _exit_code(err: Exception) -> int | None:
    """The exit code of an expected error: 2 for bad input, 1 where the input was fine but
    writing failed (a full disk or quota, in every command); None for a bug.

    ValueError (ConfigError, pydantic's ValidationError, pyarrow's ArrowInvalid, the
    library's argument checks) and OSError (missing files, permissions) are decided without
    importing the library's error classes, which load torch, so that a config typo is
    reported at once."""
    if not isinstance(err, (ValueError, OSError)):
        from tactile_compliance.data.import_report import DataImportError, ImportWriteError
        from tactile_compliance.data.store import StoreError, StoreWriteError
        from tactile_compliance.inference.pretrained import OptionalDependencyError
        from tactile_compliance.models.backbones import BackboneWeightsError
        from tactile_compliance.training.experiment import ExperimentError
        from tactile_compliance.training.hpo import TuneError

        expected = (StoreError, DataImportError, ExperimentError, TuneError, BackboneWeightsError)
        # OptionalDependencyError's message says what to pip install.
        if not isinstance(err, (*expected, OptionalDependencyError)):
            return None
        if isinstance(err, (ImportWriteError, StoreWriteError)):
            return EXIT_FAILED
    return EXIT_FAILED if _disk_full(err) else EXIT_BAD_INPUT


def _disk_full(err: BaseException) -> bool:
    """Whether ``err`` (or what caused it) is a full disk, quota or file-size limit (ENOSPC,
    EDQUOT, EFBIG): the input was fine, writing failed, so exit code 1 whichever command
    it was."""
    import errno

    seen: BaseException | None = err
    for _ in range(8):  # a short chain: the library wraps an OSError at most twice
        if seen is None:
            return False
        if isinstance(seen, OSError) and seen.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            return True
        # numpy's tofile and np.save to a real file report a short write without an errno.
        if isinstance(seen, OSError) and re.fullmatch(r"\d+ requested and \d+ written", str(seen)):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _one_line_errors(command: Any) -> Any:
    """Wrap a command so that expected errors print one line and exit with their code."""

    @functools.wraps(command)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except (typer.Exit, typer.Abort, _click_errors.ClickException, BrokenPipeError):
            raise  # click handles these (a closed pipe, e.g. `| head`: exit 1 quietly)
        except KeyboardInterrupt:
            typer.secho("interrupted; re-run the same command to continue", err=True)
            raise typer.Exit(EXIT_INTERRUPTED) from None
        except Exception as err:
            code = None if _debug else _exit_code(err)
            if code is None:
                raise
            _fail(str(err) or type(err).__name__, code)

    return run


def _element_type(shown: str | None) -> str | None:
    """``<list[Path]>`` -> ``<path>``: a repeatable parameter takes one value per use."""
    if not shown:
        return shown
    return re.sub(r"^<list\[(\w+)\]>", lambda m: f"<{m[1].lower()}>", shown)


class _Option(TyperOption):
    """An option whose help shows a value only where it takes one: typer 0.29 shows
    ``<bool>`` for every flag (``--help`` too) and ``<list[str]>`` for a repeatable option,
    which takes one ``<str>`` per use."""

    def display_type_rich(self, ctx: Any) -> str | None:
        if self.is_flag or self.count:
            return None
        return _element_type(super().display_type_rich(ctx))


class _Argument(TyperArgument):
    """An argument shown as click shows one, ``STORE`` (``[STORE]`` when optional,
    ``STORE...`` for several), where typer writes ``{STORE}`` in the usage line. Click's
    public ``get_usage_pieces`` is overridden: typer's own hooks for it differ between
    versions (0.27 and 0.29 alike wrote the braces)."""

    def get_usage_pieces(self, ctx: Any) -> list[str]:
        name = self.metavar if self.required else f"[{self.metavar}]"
        return [f"{name}..." if self.nargs != 1 else name]

    def _rich_display_name(self) -> str:
        return f"{self.metavar}..." if self.nargs != 1 else self.metavar

    def display_type_rich(self, ctx: Any) -> str | None:
        return _element_type(super().display_type_rich(ctx))


def _plain_params(params: list[Any]) -> list[Any]:
    """The parameters with the display above. typer creates its parameter objects itself
    (no hook for a class), so each is given the subclass, which only overrides display."""
    for param in params:
        if type(param) is TyperOption:
            param.__class__ = _Option
        elif type(param) is TyperArgument:
            param.__class__ = _Argument
            if param.metavar is None:
                param.metavar = param.name.upper()
    return params


def _main_with_one_line_errors(main: Any, *args: Any, **kwargs: Any) -> Any:
    """Run click's ``main``; in standalone mode a usage error (an unknown option, a value
    that is not one of the choices, a missing argument) is one line on stderr, exit 2,
    like the commands' own errors, instead of typer's framed usage block."""
    formatwarning = warnings.formatwarning  # the command may replace it (main callback)
    try:
        return _run_main(main, *args, **kwargs)
    finally:
        warnings.formatwarning = formatwarning


def _run_main(main: Any, *args: Any, **kwargs: Any) -> Any:
    if not kwargs.get("standalone_mode", True):
        return main(*args, **kwargs)
    try:
        code = main(*args, **{**kwargs, "standalone_mode": False})
    except _click_errors.ClickException as err:
        context = getattr(err, "ctx", None)
        hint = f" (see `{context.command_path} --help`)" if context is not None else ""
        # typer checks choices with pydantic, whose messages start with "Value error, ".
        message = err.format_message().replace("Value error, ", "")
        typer.secho(f"error: {message}{hint}", fg=typer.colors.RED, err=True)
        sys.exit(err.exit_code)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(EXIT_FAILED)
    # Without standalone mode click returns what the command returned (None) or the code
    # of a typer.Exit (--help, --version, _fail).
    sys.exit(code if isinstance(code, int) else 0)


class _Command(TyperCommand):
    """A command with the help display and the one-line usage errors above."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _plain_params(super().get_params(ctx))

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except _click_errors.MissingParameter as err:
            # One value only fills the last argument (`live CHECKPOINT... SOURCE`), so click
            # names the variadic one before it as missing, where the last was forgotten.
            if err.param is None or err.param.nargs != -1:
                raise
            last = [p for p in self.params if p.param_type_name == "argument"][-1]
            if err.param is last:
                raise
            raise _click_errors.UsageError(
                f"give {err.param.metavar}... and then {last.metavar}", ctx
            ) from None

    def main(self, *args: Any, **kwargs: Any) -> Any:
        return _main_with_one_line_errors(super().main, *args, **kwargs)


class _Group(TyperGroup):
    """A group with the help display and the one-line usage errors above, whose bare call
    prints its help and exits with 0 (click exits with 2)."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _plain_params(super().get_params(ctx))

    def main(self, *args: Any, **kwargs: Any) -> Any:
        return _main_with_one_line_errors(super().main, *args, **kwargs)

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        if not args and self.no_args_is_help and not ctx.resilient_parsing:
            typer.echo(ctx.get_help(), color=ctx.color)
            ctx.exit(0)
        return super().parse_args(ctx, args)


class _Cli(typer.Typer):
    """A Typer app whose every command turns expected errors into one line (see above)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(cls=_Group, no_args_is_help=True, **kwargs)

    def command(self, *args: Any, **kwargs: Any) -> Any:
        register = super().command(*args, cls=_Command, **kwargs)

        def decorator(command: Any) -> Any:
            register(_one_line_errors(command))
            return command

        return decorator


def _fail(message: str, code: int = EXIT_FAILED) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code)


def _json(document: Any) -> str:
    """JSON as the commands print (--json) and write it: indented, paths as strings."""
    return json.dumps(document, indent=2, default=str)


def _size_option(size: str | None) -> tuple[int, int] | None:
    if size is None:  # no import: image_ops loads OpenCV, which `train` does not need yet
        return None
    from tactile_compliance.data.image_ops import parse_size

    try:
        return parse_size(size)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from err


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"tactile-compliance {__version__}")
        raise typer.Exit()


def main(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version_callback, is_eager=True, help="Show the version."
        ),
    ] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the traceback of an error, not one line.")
    ] = False,
) -> None:
    """Estimate an object's Young's modulus from one GelSight grasp."""
    global _debug
    _debug = debug
    if not debug:  # --debug keeps Python's form (file:line: Category: message)
        # Only the text changes (formatwarning, not showwarning), so a caller that records
        # warnings (warnings.catch_warnings, pytest.warns) still gets them; restored when
        # the command ends, for a program that runs commands in its own process.
        # (_main_with_one_line_errors puts the previous one back.)
        warnings.formatwarning = _format_warning


def _format_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    line: str | None = None,
) -> str:
    """A warning as the command's one line, ``warning: MESSAGE``, not the file and line
    inside a library that raised it (pydantic's ``main.py:792: UserWarning``)."""
    text = " ".join(str(message).split())
    kind = "" if category is UserWarning else f" ({category.__name__})"
    return f"warning: {text}{kind}\n"


def _existing_dir(path: Path, what: str) -> Path:
    """``path`` when it is a directory; else a ValueError (one line, before the heavy
    imports) naming it and, when a sibling's name is close, that sibling (did you mean)."""
    if path.is_dir():
        return path
    from tactile_compliance.suggest import did_you_mean

    parent = path.parent if str(path.parent) else Path(".")
    try:
        siblings = [p.name for p in parent.iterdir() if p.is_dir()] if parent.is_dir() else []
    except OSError:
        siblings = []
    hint = did_you_mean(path.name, siblings, cutoff=0.3)  # a folder holds few names
    if hint:
        close = hint.removeprefix(" (did you mean '").split("'")[0]
        hint = f" (did you mean {parent / close}?)"
    kind = "not a directory" if path.exists() else "no such directory"
    raise ValueError(f"{path}: {kind}{hint}; give the {what}")


def _load_config(
    config: str,
    options: list[str],
    overrides: list[str] | None,
    values: dict[str, Any] | None = None,
) -> object:
    """The config with the command's options applied (``options`` as ``key=value``,
    ``values`` already parsed), then the --set overrides (which win)."""
    from tactile_compliance.config import load_config

    return load_config(config, [*options, *(overrides or [])], values)
