"""Errors that the `pvo` command reports as one line (no traceback)."""

from __future__ import annotations


class PvoError(Exception):
    """A user-facing error; ``str()`` is one line naming what is wrong and where."""


class BagError(PvoError):
    """A bag is missing, truncated, corrupt or would be overwritten."""


class UnknownMessageType(PvoError):
    """A message type that no installed package defines."""
