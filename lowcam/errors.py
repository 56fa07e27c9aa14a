"""One exception type for every user-facing problem.

Each message is a single line that names the file (or profile key) and the problem, so the CLI can print it
as it is, without a traceback.

Contents
--------
- :class:`LowcamError`: bad input or configuration: a missing or corrupt file, a wrong size, an unknown key
- :class:`ProfileError`: a profile that does not validate: unknown key, wrong type, value out of range
- :class:`NotFitted`: a fit that cannot be made from the data at hand, with the one-line reason why
"""


class LowcamError(Exception):
    """Bad input or configuration: a missing or corrupt file, a wrong size, an unknown profile key."""


class ProfileError(LowcamError):
    """A profile that does not validate: unknown key, wrong type, value out of range."""


class NotFitted(Exception):
    """A fit that cannot be made from the data at hand (a diagnosis candidate, a plate estimate): the message is
    the one-line reason, shown to the user beside the candidate's name ("the captures never reach the corners")."""
