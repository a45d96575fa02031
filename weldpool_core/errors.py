"""Errors a user can meet: each one ends in a clear sentence that says what to do."""

from __future__ import annotations


class WeldpoolError(Exception):
    """Base of every error that carries a message meant for a user."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class InvalidInputError(WeldpoolError):
    """The input (an image, a mask, a parameter) cannot be used as given."""


class WeightsUnavailableError(WeldpoolError):
    """Model weights are neither in a local directory nor in the hub cache, nor downloadable."""
