"""Hydra's shell completion for ``box-pipeline``, offering only real choices.

``box-pipeline -sc install=bash`` prints Hydra's bash function; the shell then asks
``box-pipeline -sc query=bash`` (with ``COMP_LINE``) for the words that complete a command
line.  Hydra answers from every config its search path holds, so ``domain=`` would also
offer ``grasp_arm_schema``: the structured-config schemas that the YAML files in ``conf/``
name in their ``defaults`` (they have to live in their group for that).  Hydra has no way
to hide a config from completion, so its answer is filtered here: in a group of ``conf/``,
only the group's YAML files are choices (the same list ``--help`` shows).
"""

from __future__ import annotations

import contextlib
import io
import sys
from collections.abc import Iterator

from pipeline.configs import CONF_DIR, choices


def is_query(args: list[str]) -> bool:
    """Whether ``args`` ask Hydra for completions (``-sc query=SHELL``)."""
    return bool({"-sc", "--shell-completion"} & set(args)) and \
        any(a.startswith("query=") for a in args)


def real_choices_only(words: list[str]) -> list[str]:
    """``words`` without ``group=option`` (also ``+group=``, ``~group=``) whose option is
    not one of the group's YAML files in ``conf/``."""
    groups = {p.name: set(choices(p.name)) for p in CONF_DIR.iterdir() if p.is_dir()}

    def real(word: str) -> bool:
        group, eq, option = word.lstrip("+~").partition("=")
        return not (eq and option and group in groups and option not in groups[group])

    return [w for w in words if real(w)]


@contextlib.contextmanager
def filtered_answer() -> Iterator[None]:
    """Capture what Hydra prints while it answers a completion query and print it again
    without the schema entries, one word per line or on one line as Hydra wrote it (fish
    reads lines, bash words)."""
    answer = io.StringIO()
    try:
        with contextlib.redirect_stdout(answer):
            yield
    finally:
        text = answer.getvalue()
        words = real_choices_only(text.split())
        sys.stdout.write(("\n" if "\n" in text.strip() else " ").join(words) + "\n")
        sys.stdout.flush()
