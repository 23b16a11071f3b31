"""The exceptions ccf_ros raises for users: one line each, meant to be shown without a traceback.

Anything else that escapes is a bug and shows its traceback. No ROS import.
"""

from __future__ import annotations


class CcfError(Exception):
    """Base of every user-facing ccf_ros error; the message is one line for the user."""


class BagError(CcfError):
    """A bag cannot be read or written as asked (missing, unreadable, truncated, wrong topic, exists)."""


class ParameterError(CcfError, ValueError):
    """An invalid, unknown or inapplicable parameter (name and offending value in the message).

    Also a ``ValueError``, the type the core raises for invalid values, so existing handlers keep working.
    """
