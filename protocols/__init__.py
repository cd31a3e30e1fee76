"""Pure codecs (MSP, stand wire formats, MAVLink helpers on pymavlink) and byte transports.

Importing it has no side effect: thrustmap's pyserial URL handlers (``sim://``, ``record://``,
``replay://``) are registered where a transport is opened (``transport.open_transport``).
"""

if __name__ != "thrustmap.protocols":  # the checkout's top-level folder, imported by its bare name
    raise ImportError(f"import thrustmap.protocols, not {__name__}: one module, one name")
