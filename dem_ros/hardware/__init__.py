"""The hardware side: the board ↔ PC device link, the driver and the rig emulator.

- :mod:`dem_ros.hardware.link` — the frames (handshake, sensor, command, configuration), their
  fixed little-endian layout with a CRC-32, ``encode``/``decode`` and
  :class:`~dem_ros.hardware.link.LinkError`. The protocol is documented in
  ``docs/hardware-link.md`` and defined by ``tests/hardware/vectors/frames.txt``.
- :mod:`dem_ros.hardware.boardcfg` — the board's configuration the driver sends it over the link (packed
  from the ``hw_driver`` parameters), its CRC-32, and the rules a board checks before it runs one.
- :mod:`dem_ros.hardware.framing` — COBS framing for byte streams (serial).
- :mod:`dem_ros.hardware.channel` — UDP, serial and pty channels carrying frames.

Nothing here imports a middleware: the link is plain Python, testable alone.
"""
