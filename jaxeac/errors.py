"""User-facing errors.

`UsageError` marks bad input (a malformed map, a negative rate, an unwritable
output folder, ...). The CLI turns it into a one-line ``error: ...`` on stderr
and exit code 2; library users get an ordinary ``ValueError`` subclass.
"""

from __future__ import annotations


class UsageError(ValueError):
    """Bad input: the message names the problem and how to fix it, on one line."""
