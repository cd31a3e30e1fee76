"""One module per DIY stand firmware: each defines ``PRESET`` (a ``LineStandSpec`` written from
that firmware's source at a pinned commit, cited in ``source``) and optionally ``ALIASES``.
``thrustmap.protocols.stands.line_presets`` finds them; nothing is re-exported here."""
