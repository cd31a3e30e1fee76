"""Pure codecs (MSP, stand wire formats, MAVLink helpers on pymavlink) and byte transports.

Importing it has no side effect: thrustmap's pyserial URL handlers (``sim://``, ``record://``,
``replay://``) are registered where a transport is opened (``transport.open_transport``).
"""
