"""Exceptions raised by tightscan.

A problem with one tightening is never an exception: it is a result row whose ``status`` says
what is wrong. Exceptions are for problems with a whole table, file or parameter.
"""

from __future__ import annotations

__all__ = ["TightscanError", "SchemaError", "InvalidParameterError", "DataFileError"]


class TightscanError(Exception):
    """Base class of every tightscan exception."""


class SchemaError(TightscanError, ValueError):
    """The table does not follow the data contract. ``column`` names the offending column."""

    def __init__(self, message: str, column: str | None = None) -> None:
        super().__init__(message)
        self.column = column


class InvalidParameterError(TightscanError, ValueError):
    """A parameter is out of its domain. ``parameter`` names it."""

    def __init__(self, message: str, parameter: str | None = None) -> None:
        super().__init__(message)
        self.parameter = parameter


class DataFileError(TightscanError, OSError):
    """A data file cannot be found or read. ``path`` names it."""

    def __init__(self, message: str, path: str) -> None:
        super().__init__(message)
        self.path = path
