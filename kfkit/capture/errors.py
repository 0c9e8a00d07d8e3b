"""The capture errors: each a problem the user can fix, its message saying what happened and what to do.

:class:`CaptureError` is the family; a board's port raises the first group (:mod:`.ports`,
:mod:`.recorder`), a phone running phyphox the :class:`PhoneError` group (:mod:`.phyphox_http`).
"""

from __future__ import annotations


class CaptureError(RuntimeError):
    """A capture problem the user can fix; the message says what happened and what to do."""


class PortNotFoundError(CaptureError):
    pass


class PortAddressError(CaptureError, ValueError):
    """A port name or URL kfkit cannot read (an unknown scheme, no host, a bad option): the message names the
    port and lists the forms a port takes (:func:`kfkit.capture.ports.check_port`)."""


class PortBusyError(CaptureError):
    pass


class PortPermissionError(CaptureError):
    pass


class WrongBaudError(CaptureError):
    pass


class NoDataError(CaptureError):
    pass


class ProtocolVersionError(CaptureError):
    pass


class BoardDisconnectedError(CaptureError):
    pass


class PhoneError(CaptureError):
    """A problem with the phone or phyphox; the message says what to do."""


class PhoneUnreachableError(PhoneError):
    pass


class RemoteAccessOffError(PhoneError):
    pass


class PhoneExperimentError(PhoneError):
    pass


class PhoneStoppedError(PhoneError):
    pass
