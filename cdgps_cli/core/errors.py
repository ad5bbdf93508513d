"""User-facing error type.

Every problem caused by the user's input (a bad config, a malformed log, an option out of range)
is raised as :class:`CdgpsError`.  The command-line layer prints its message on stderr without a
traceback and exits with status 2; programming errors keep their tracebacks.
"""


class CdgpsError(Exception):
    """An error in the user's input, with a message that says where and what was expected."""


class AmbiguityError(ValueError):
    """Invalid input to, or failure of, integer ambiguity resolution (:mod:`cdgps_cli.estimation.ambiguity`; here so
    that the command line names it without importing the numerics)."""


def join_problems(header: str, problems: list[str]) -> str:
    """Format a list of problems as one message (gnss_lib_py style: list everything at once)."""
    if len(problems) == 1:
        return f"{header}: {problems[0]}"
    lines = "\n".join(f"  - {p}" for p in problems)
    return f"{header}: {len(problems)} problems\n{lines}"
