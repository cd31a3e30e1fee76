"""Pure codecs (MSP, stand wire formats, MAVLink helpers on pymavlink) and byte transports.

Importing this package registers thrustmap's pyserial URL handlers (``sim://``, ``record://``,
``replay://``); see ``thrustmap.protocols.transport``.
"""

from thrustmap.protocols import transport as _transport

_transport.register_url_handlers()
