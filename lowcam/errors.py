"""One exception type for every user-facing problem.

Each message is a single line that names the file (or profile key) and the problem, so the CLI can print it
as it is, without a traceback.

Contents
--------
- :class:`LowcamError`: bad input or configuration: a missing or corrupt file, a wrong size, an unknown key
- :class:`ProfileError`: a profile that does not validate: unknown key, wrong type, value out of range
- :class:`DiskFull`: an output could not be written for want of space (or quota): a job stops there
- :class:`UntrustedPlugin`: a profile names a plug-in effect of a module the user has not trusted
- :class:`NotFitted`: a fit that cannot be made from the data at hand, with the one-line reason why
"""


class LowcamError(Exception):
    """Bad input or configuration: a missing or corrupt file, a wrong size, an unknown profile key."""


class ProfileError(LowcamError):
    """A profile that does not validate: unknown key, wrong type, value out of range."""


class DiskFull(LowcamError):
    """An output could not be written for want of space, quota or file size (ENOSPC, EDQUOT, EFBIG): every later
    frame would fail the same way, so a job stops at the first such write and says how to resume."""


class UntrustedPlugin(ProfileError):
    """A profile names a plug-in effect (``"module:Class"``) of a module the user has not trusted; nothing was
    imported. The message says how to allow it."""

    def __init__(self, source: str, effect_type: str, module: str):
        self.source, self.effect_type, self.module = source, effect_type, module
        super().__init__(f"{source}: the profile names plug-in effect '{effect_type}' of an untrusted module; "
                         f"{self.how_to_allow}")

    @property
    def how_to_allow(self) -> str:
        m = self.module
        return (f"allow it with --plugin {m} or LOWCAM_PLUGINS={m} (in Blender: the Lowcam add-on's Trusted "
                "Plug-ins preference, for .blend files allowed to run scripts)")


class NotFitted(Exception):
    """A fit that cannot be made from the data at hand (a diagnosis candidate, a plate estimate): the message is
    the one-line reason, shown to the user beside the candidate's name ("the captures never reach the corners")."""
