"""The live view: the running graph as a Foxglove WebSocket server (``dem-ros view``).

``server``   :class:`~.server.ViewServer`: every ``/dem`` topic and ``/diagnostics`` forwarded as received
             (``ros2msg`` schema + CDR, no decode), the nodes' parameters and hw_driver's services;
``graph``    :class:`~.graph.GraphAccess`: the nodes' parameter services and hw_driver's Trigger services,
             validated as ``dem-ros param set`` validates;
``layout``   the Foxglove layout shipped as ``config/foxglove/dem_ros.json``;
``client``   a minimal client of the Foxglove WebSocket protocol (``dem-ros view --probe``, the tests).

Needs the ``view`` extra (``pip install 'dem_ros[view]'``: ``foxglove-sdk``, ``websockets``).
"""

__all__ = ["SUBPROTOCOL"]

#: the WebSocket subprotocol foxglove-sdk servers accept
SUBPROTOCOL = "foxglove.sdk.v1"
