"""The failures a command reports in one line, ``twomem_post: error: <where>: <why>``, with
the exit status the command line returns (the statuses twomem itself uses: 2 for bad input or
usage, 3 for the environment)."""
from __future__ import annotations


class PostError(Exception):
    """A failure of a command's input: ``where`` names the file or option, ``why`` says why."""
    status = 2

    def __init__(self, where, why: str):
        super().__init__(f"{where}: {why}")
        self.where = str(where)
        self.why = why


class ResultError(PostError):
    """A result file that cannot be read or is not a twomem result."""

    @property
    def path(self) -> str:
        return self.where


class EnvironmentFailure(PostError):
    """Something outside the input is missing or broken (e.g. no twomem executable)."""
    status = 3
