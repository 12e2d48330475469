"""Bad user input, and the one way every command reports it: one line `error: <message>` and exit code 2.

An InputError is raised where a config value, a data folder or an input file turns out unusable,
before anything is run; its message names the key and value, or the file, and says what to do. It
is a ValueError (MissingInputError a FileNotFoundError too), so callers that catch those still do.

Hydra reports its own composition errors (an unknown option `loss=bogus`, a key the config lacks
`stage2.max_epoch=3`, an override it cannot parse, a `???` value left unset) as a block of text, a
hint about HYDRA_FULL_ERROR and exit code 1. `describe` turns those, and InputError, into one line
naming the key, the value and the choices (with the close match of a typo). `reporting_bad_input`
wraps a whole command; `bad_input_exit` serves code that catches errors itself (train.py's and
eval.py's task functions, which clean up a run folder first). With HYDRA_FULL_ERROR=1 nothing is
translated: each error keeps its full traceback. Anything else (a bug, a full disk) keeps its
traceback and exit code 1.
"""

from __future__ import annotations

import difflib
import os
import re
import sys
from contextlib import contextmanager
from typing import Iterator

from hydra.errors import (
    ConfigCompositionException,
    InstantiationException,
    MissingConfigException,
    OverrideParseException,
)
from omegaconf.errors import (
    ConfigAttributeError,
    ConfigKeyError,
    InterpolationResolutionError,
    MissingMandatoryValue,
)

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command stopped by Ctrl+C
FULL_ERROR = "HYDRA_FULL_ERROR"  # Hydra's switch; "1": full tracebacks, nothing translated
# Set beside FULL_ERROR while reporting_bad_input has set it (and inherited by processes started then,
# e.g. DDP ranks): Hydra then raises its errors here instead of printing them, and the user did not ask.
OURS = "USHAPE_FULL_ERROR_IS_OURS"


class InputError(ValueError):
    """A config value, data folder or input file no run could use; the message says which and what to do."""


class MissingInputError(InputError, FileNotFoundError):
    """An input file or folder that does not exist where the config or the command line says it is."""


def full_errors_wanted() -> bool:
    """Whether the user set HYDRA_FULL_ERROR=1: every error then keeps its traceback."""
    return os.environ.get(FULL_ERROR) == "1" and os.environ.get(OURS) != "1"


def describe(err: BaseException) -> str | None:
    """The one-line message of a bad-input error (InputError, Hydra's composition errors); None for others."""
    if isinstance(err, InputError):
        return str(err)
    if isinstance(err, InstantiationException):  # a configured object refused its arguments
        if str(err).startswith("Error locating target"):  # a `_target_` that names no importable object
            target = re.search(r"target '([^']+)'", str(err))
            name = target.group(1) if target else "?"
            return f"{_full_key(err)}._target_={name}: no such class or function can be imported; check its spelling"
        cause = _cause(err, (InputError, MissingMandatoryValue, InterpolationResolutionError))
        if cause is None:
            return None
        return describe(cause) if not isinstance(cause, InputError) else f"{_full_key(err)}: {cause}"
    if isinstance(err, MissingConfigException) and err.missing_cfg_file and err.options is not None:
        return unknown_option(err.missing_cfg_file, list(err.options))
    if isinstance(err, OverrideParseException):
        return f"cannot read the override {err.override!r}: {_one_line(err.message)}"
    if isinstance(err, ConfigCompositionException):
        cause = err.__cause__
        if isinstance(cause, (ConfigKeyError, ConfigAttributeError)) and cause.full_key:
            return unknown_key(cause.full_key, _keys(cause.parent_node), _override_value(cause.full_key))
        return _one_line(str(err))
    if isinstance(err, MissingMandatoryValue):
        key = err.full_key or "a value"
        return f"{key} has no value (??? in its config): give it on the command line, {key}=<value>"
    if isinstance(err, InterpolationResolutionError):
        return f"{err.full_key}: {_one_line(str(err))}"
    return None


def unknown_option(missing: str, options: list[str]) -> str:
    """`loss=bogus`: Hydra found no conf/loss/bogus.yaml."""
    group, _, option = missing.rpartition("/")
    message = f"{group}={option}: no such option of the config group {group}; choose one of {', '.join(options)}"
    close = difflib.get_close_matches(option, options, n=1)
    if close:
        message += f" (did you mean {group}={close[0]}?)"
    return message + f"; a new option is a file conf/{group}/<name>.yaml"


def unknown_key(full_key: str, keys: list[str], value: str | None) -> str:
    """`stage2.max_epoch=3`: the config has no such key; its close match, and the keys that are there."""
    parent, _, key = full_key.rpartition(".")
    where = parent or "the config"
    message = f"{full_key}={value if value is not None else '...'}: {where} has no key {key}"
    close = difflib.get_close_matches(key, keys, n=1)
    if close:
        message += f"; did you mean {f'{parent}.' if parent else ''}{close[0]}?"
    if keys:
        message += f" (its keys: {', '.join(keys)})"
    return message + f"; +{full_key}={value if value is not None else '...'} adds a new key"


def bad_input_exit(err: BaseException) -> SystemExit | None:
    """For bad input: print `error: <message>` and give the SystemExit(2) to raise; None otherwise."""
    message = None if full_errors_wanted() else describe(err)
    if message is None:
        return None
    print(f"error: {message}", file=sys.stderr)
    return SystemExit(EXIT_BAD_INPUT)


@contextmanager
def reporting_bad_input() -> Iterator[None]:
    """Run a command inside: bad input ends it with one line and exit code 2 (SystemExit); Hydra raises
    its composition errors here rather than printing them and exiting 1 itself."""
    if full_errors_wanted():
        yield
        return
    saved = {name: os.environ.get(name) for name in (FULL_ERROR, OURS)}
    os.environ.update({FULL_ERROR: "1", OURS: "1"})
    try:
        yield
    except Exception as err:
        stop = bad_input_exit(err)
        if stop is None:
            raise
        raise stop from None
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _cause(err: BaseException, types: tuple[type[BaseException], ...]) -> BaseException | None:
    """The first exception of `types` along err's chain of causes (Hydra wraps a target's error in its own)."""
    seen = err.__cause__ or err.__context__
    while seen is not None and not isinstance(seen, types):
        seen = seen.__cause__ or seen.__context__
    return seen


def _full_key(err: InstantiationException) -> str:
    """The config key of the object Hydra failed to build (its message ends with `full_key: data`)."""
    found = re.search(r"full_key: (\S+)", str(err))
    return found.group(1) if found else "config"


def _keys(node) -> list[str]:
    try:
        return [str(key) for key in node.keys() if key != "hydra"]
    except Exception:  # no mapping (a value, None): nothing to suggest
        return []


def _override_value(full_key: str) -> str | None:
    """The value the command line gave `full_key` (`stage2.max_epoch=3` -> "3"), if it did."""
    for arg in sys.argv[1:]:
        key, sep, value = arg.lstrip("+~").partition("=")
        if sep and key == full_key:
            return value
    return None


def _one_line(text: str) -> str:
    """Hydra's lines as one sentence each, on one line."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return " ".join(line if line[-1] in ".:;?!" else f"{line}." for line in lines)
