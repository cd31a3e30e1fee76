"""``udpout://host:port`` — see ``protocol_udpin`` (one implementation for both)."""

from thrustmap.protocols.urlhandlers.protocol_udpin import Serial, UdpSerial

__all__ = ["Serial", "UdpSerial"]
