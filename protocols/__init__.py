"""Pure codecs (MSP, stand wire formats, MAVLink helpers on pymavlink) and byte transports.

Importing this package registers thrustmap's pyserial URL handlers (``sim://``, ``record://``,
``replay://``); see ``thrustmap.protocols.transport``.
"""

if __name__ != "thrustmap.protocols":  # the checkout's top-level folder, imported by its bare name
    raise ImportError(f"import thrustmap.protocols, not {__name__}: one module, one name")


from thrustmap.protocols import transport as _transport

_transport.register_url_handlers()
