"""The rclpy-free node: Cyclone DDS (PyPI ``cyclonedds``) speaking ROS 2 on the wire.

One DDS participant per process (shared by all nodes of the process, like an
rclpy context), configured as rmw_cyclonedds configures it (see
:mod:`.wire`). Each node has a wait set; :meth:`DdsNode.spin` waits on it
until the next timer deadline and then, on the calling thread, takes the
samples of every reader and runs the callbacks and due timers one at a time.

Graph visibility: the participant publishes ``ros_discovery_info``
(rmw_dds_common ParticipantEntitiesInfo: node name, namespace, reader and
writer GIDs), so ``ros2 node list`` and ``ros2 topic info -v`` see the nodes.
Sources: :meth:`DdsNode.subscribe_with_source` hands each sample's writer GID (its
``publication_handle`` looked up among the reader's matched publications, cached per handle) to
the callback, and :meth:`DdsNode.publisher_gids` joins the live writers of a topic (the
DCPSPublication built-in topic) with the writer GIDs each node announces in
``ros_discovery_info`` (as ``rmw_dds_common``'s graph cache does).
Parameters are served over the six ``rcl_interfaces`` services
(``rq/<node>/<srv>Request`` / ``rr/<node>/<srv>Reply``) and changes are
announced on ``/parameter_events``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from cyclonedds._clayer import ddspy_write
from cyclonedds.core import ReadCondition
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic as DdsTopic

from ... import contract
from ...contract import QoS, Topic
from .. import paramvalue as pv
from ..api import (
    CallbackGuard,
    OnChange,
    RawCallback,
    ServiceCallback,
    SourcedCallback,
    TransportError,
    gid16,
    node_fqn,
)
from ..lifecycle import LifecycleInterface, LifecycleMachine, event_topic
from ..logger import NodeLogger
from ..loop import LocalSubscription, SourcedLocalSubscription, deliver_local
from ..parameters import ParameterStore
from ..rosargs import RosArgs, initial_parameters, parse_ros_args
from . import fastcdr, lifecycle_msgs, msgs, srvs, wire
from .executor import ANY_SAMPLE, DdsExecutor, DdsTimer

__all__ = ["QOS_SERVICES", "DdsExecutor", "DdsNode", "DdsPublisher", "DdsTimer", "Participant"]
#: rmw_qos_profile_services_default
QOS_SERVICES = QoS(reliable=True, transient_local=False, depth=10)
#: rcl's rosout QoS (Jazzy: transient local, depth 1000)
QOS_ROSOUT = QoS(reliable=True, transient_local=True, depth=1000)
#: how often an intra-process publisher re-reads its count of remote subscribers
_REMOTE_CHECK_NS = 100_000_000
#: writer GIDs cached per publication handle and sourced reader (a graph's writers on one topic: a few)
_SOURCE_CACHE = 256
#: at most this many live writers are read from the DCPSPublication built-in topic per query
_MAX_WRITERS = 100_000


def _guid_bytes(entity: Any) -> bytes:
    return bytes(entity.get_guid().bytes)


class Participant:
    """The process-wide DDS participant plus the ``ros_discovery_info`` writer."""

    _instance: Participant | None = None
    _lock = threading.Lock()

    def __init__(self, settings: wire.Settings):
        from cyclonedds.qos import Policy, Qos

        self.settings = settings
        try:
            self.domain = Domain(settings.domain_id, wire.domain_config(settings))
            self.dp = DomainParticipant(settings.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;")))
        except Exception as exc:  # DDSException: bad CYCLONEDDS_URI, no interface, ...
            raise TransportError(
                f"cannot create a DDS participant in domain {settings.domain_id} "
                f"(discovery {settings.discovery_range}): {exc}"
            ) from None
        self.gid = self._gid(_guid_bytes(self.dp))
        self._topics: dict[str, DdsTopic] = {}
        self._nodes: list[DdsNode] = []
        types = msgs.gid_types(settings.gid_size)
        self._Gid = types["Gid"]
        self._NEI = types["NodeEntitiesInfo"]
        self._PEI = types["ParticipantEntitiesInfo"]
        info_qos = QoS(reliable=True, transient_local=True, depth=1)
        ud = wire.user_data_for_endpoint("rmw_dds_common/msg/ParticipantEntitiesInfo", settings.distro)
        self._info_writer = DataWriter(
            self.dp, self.topic("ros_discovery_info", self._PEI), qos=wire.dds_qos(info_qos, ud)
        )
        self._graph_readers: tuple[Any, Any, Any] | None = None  # made by the first graph query
        #: participant GID -> {node /ns/name -> writer GIDs}, from ros_discovery_info
        self._node_writers: dict[bytes, dict[str, set[bytes]]] = {}

    # -- process singleton ---------------------------------------------------------
    @classmethod
    def get(cls, domain_id: int | None = None) -> Participant:
        settings = wire.settings_from_env(domain_id)
        with cls._lock:
            inst = cls._instance
            if inst is not None and inst.settings != settings:
                raise TransportError(
                    f"this process already has a DDS participant in domain {inst.settings.domain_id} "
                    f"({inst.settings.distro}); one participant per process"
                )
            if inst is None:
                inst = cls._instance = Participant(settings)
            return inst

    def _gid(self, guid16: bytes) -> bytes:
        return guid16 + b"\0" * (self.settings.gid_size - len(guid16))

    def gid_of(self, entity: Any) -> bytes:
        """The ROS GID of a DDS entity (its GUID, zero-padded to the distro's GID size)."""
        return self._gid(_guid_bytes(entity))

    def topic(self, name: str, cls: type) -> DdsTopic:
        t = self._topics.get(name)
        if t is None:
            t = self._topics[name] = DdsTopic(self.dp, name, cls)
        elif t.data_type is not cls:
            raise TransportError(f"DDS topic {name!r} already exists with type {t.data_type.__name__}")
        return t

    # -- graph ---------------------------------------------------------------------
    @property
    def has_nodes(self) -> bool:
        """True while a node of this process uses the participant."""
        return bool(self._nodes)

    def add_node(self, node: DdsNode) -> None:
        self._nodes.append(node)

    def remove_node(self, node: DdsNode) -> None:
        if node in self._nodes:
            self._nodes.remove(node)
            self.publish_graph()
        if not self._nodes:
            with Participant._lock:
                if Participant._instance is self:
                    Participant._instance = None
            try:
                self.dp.__del__()  # dds_delete: all readers, writers and topics with it
                self.domain.__del__()
            except Exception:
                pass

    def release_if_unused(self) -> None:
        """Delete the participant when no node uses it (after a one-shot client call)."""
        if not self._nodes:
            self.remove_node(None)  # type: ignore[arg-type]

    def _graph(self) -> tuple[Any, Any, Any]:
        """(ros_discovery_info reader, DCPSPublication reader, its alive-instances condition), made once."""
        if self._graph_readers is None:
            from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
            from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
            from cyclonedds.qos import Policy, Qos
            from cyclonedds.util import duration

            # ros_discovery_info is keyless: keep every sample until taken (each participant's newest wins)
            qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.TransientLocal,
                      Policy.History.KeepAll)
            info = DataReader(self.dp, self.topic("ros_discovery_info", self._PEI), qos=qos)
            pubs = BuiltinDataReader(self.dp, BuiltinTopicDcpsPublication)
            alive = ReadCondition(pubs, SampleState.Any | ViewState.Any | InstanceState.Alive)
            self._graph_readers = (info, pubs, alive)
        return self._graph_readers

    def node_writers(self, node: str) -> set[bytes]:
        """GIDs (16 bytes) of every writer that node ``node`` (``/ns/name``) announces in ros_discovery_info."""
        info, _pubs, _alive = self._graph()
        for pei in info.take(N=4096):
            self._node_writers[gid16(pei.gid.data)] = {
                node_fqn(n.node_name, n.node_namespace): {gid16(g.data) for g in n.writer_gid_seq}
                for n in pei.node_entities_info_seq
            }
        return set().union(*(nodes.get(node, ()) for nodes in self._node_writers.values()))

    def publisher_gids(self, dds_topic: str, node: str) -> frozenset[bytes]:
        """GIDs (16 bytes) of the live writers on ``dds_topic`` that node ``node`` (``/ns/name``) announces
        (DCPSPublication: ~1 ms a writer through the Python binding; a sourced reader's matched writers are far
        cheaper, :meth:`DdsNode.publisher_gids`)."""
        mine = self.node_writers(node)
        if not mine:
            return frozenset()
        _info, pubs, alive = self._graph()
        live = {gid16(p.key.bytes) for p in pubs.read(N=_MAX_WRITERS, condition=alive) if p.topic_name == dds_topic}
        return frozenset(mine & live)

    def local_writers(self, dds_topic: str) -> set[bytes]:
        """GIDs (16 bytes) of this process's live writers on ``dds_topic``."""
        return {g for n in self._nodes for t, g in n._writer_topics if t == dds_topic}

    def publish_graph(self) -> None:
        """Publish ParticipantEntitiesInfo naming every node and its endpoint GIDs."""
        g = self._Gid
        infos = [
            self._NEI(
                node_namespace=n.namespace,
                node_name=n.name,
                reader_gid_seq=[g(data=list(x)) for x in n._reader_gids],
                writer_gid_seq=[g(data=list(x)) for x in n._writer_gids],
            )
            for n in self._nodes
        ]
        self._info_writer.write(self._PEI(gid=g(data=list(self.gid)), node_entities_info_seq=infos))


class DdsPublisher:
    """Writes messages of one topic; :meth:`publish_raw` sends ready CDR bytes.

    With ``local`` (intra-process, see :mod:`.executor`) a message goes to the
    subscriptions of the same executor through its queue, and to DDS only
    while a remote subscriber is matched.
    """

    def __init__(self, writer: DataWriter, cls: type, local: list[LocalSubscription] | None = None,
                 queue: Any = None, gid: bytes = b""):
        self.writer = writer
        self.gid = gid  # this writer's GID (16 bytes), handed to intra-process sourced subscriptions
        self._writer = writer
        self._cls = cls
        self.ref = self._ref = writer._ref
        self._encode = fastcdr.encoder(cls)
        self._local = local
        self._queue = queue
        self._remote = 0
        self._remote_checked = 0

    def _cdr(self, msg: Any) -> bytes:
        data = self._encode(msg) if self._encode is not None and type(msg) is self._cls else msg.serialize()
        # Cyclone expects the payload padded to a multiple of 4 (as DataWriter.write does)
        pad = -len(data) % 4
        return data + b"\0" * pad if pad else data

    def _remote_subscribers(self) -> int:
        now = time.monotonic_ns()
        if now >= self._remote_checked:
            self._remote_checked = now + _REMOTE_CHECK_NS
            self._remote = self._writer.get_publication_matched_status().current_count
        return self._remote

    def publish(self, msg: Any) -> None:
        local = self._local
        data: bytes | None = None
        if local is not None:
            data = deliver_local(local, self._queue, msg, self.gid, self._cdr)
            if not self._remote_subscribers():
                return
        ret = ddspy_write(self._ref, data if data is not None else self._cdr(msg))
        if ret < 0:
            raise TransportError(f"DDS write failed on {self._writer.topic.name} (code {ret})")

    def publish_raw(self, data: bytes) -> None:
        """Send serialized CDR (with encapsulation header), e.g. a sample from a bag."""
        pad = -len(data) % 4
        ret = ddspy_write(self._ref, bytes(data) + b"\0" * pad if pad else bytes(data))
        if ret < 0:
            raise TransportError(f"DDS write failed on {self._writer.topic.name} (code {ret})")

    @property
    def subscription_count(self) -> int:
        """Matched subscriptions: remote ones plus those of the same executor (intra-process)."""
        return len(self._writer.get_matched_subscriptions()) + len(self._local or ())


class DdsNode:
    """A ROS 2 node on plain Cyclone DDS. Create it with :func:`dem_ros.transport.make_node`."""

    transport = "dds"

    def __init__(self, name: str, args: list[str] | None = None, *, domain_id: int | None = None,
                 executor: DdsExecutor | None = None, ignore_undeclared: bool = False):
        """``executor``: share one (e.g. intra-process) executor with other nodes of this process;
        by default the node has its own. ``ignore_undeclared``: a ``-p name:=value`` this node
        does not declare is left to the other nodes of the process (composition) instead of
        being an error."""
        self._ros_args: RosArgs = parse_ros_args(args)
        self._given_name = name  # node-targeted ROS arguments name this one
        self.name = self._ros_args.name_for(name)
        self.namespace = self._ros_args.namespace_for(name)
        self._p = Participant.get(domain_id)
        self._ignore_undeclared = ignore_undeclared
        self._reader_gids: list[bytes] = []
        self._writer_gids: list[bytes] = []
        self._writer_topics: list[tuple[str, bytes]] = []  # (DDS topic, GID16) of each writer
        #: DDS topic -> (the reader of a sourced subscription, its GID cache by publication handle)
        self._sourced: dict[str, tuple[DataReader, dict[int, bytes]]] = {}
        self._pending_replies: list[tuple[int, Any, bytes, str]] = []
        self._shutdown = False
        self._ex = executor if executor is not None else DdsExecutor(self._p)
        if self._ex.participant is not self._p:
            raise TransportError("the executor belongs to another DDS participant")
        self._ex.add_node(self)
        self._params: ParameterStore | None = None
        self._guard = CallbackGuard(lambda: self.logger)
        self._p.add_node(self)
        self.logger = NodeLogger(lambda: self.logger_name)
        self._p.publish_graph()
        # composed, the container's own readers take no sample of its participant over DDS: /rosout goes to them
        # intra-process, as every topic of the container (its recorder is its first node: it has every record)
        self._rosout_pub = self._make_writer("/rosout", "rcl_interfaces/msg/Log", QOS_ROSOUT,
                                             intra=self._ex.intra_process)
        self.logger.sink = self._rosout
        self._events_pub = self.publisher(contract.PARAMETER_EVENTS)
        self._csid = 0

    def _rosout(self, level: str, name: str, text: str, t_ns: int) -> None:
        """One log record on /rosout (rcl_interfaces/msg/Log, as rcl publishes it)."""
        self._rosout_pub.publish(msgs.Log(
            stamp=msgs.Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), level=NodeLogger.LEVELS[level],
            name=name, msg=text, file="", function="", line=0))

    # -- names -----------------------------------------------------------------------
    @property
    def fully_qualified_name(self) -> str:
        return self.namespace.rstrip("/") + "/" + self.name

    @property
    def logger_name(self) -> str:
        return self.fully_qualified_name.lstrip("/").replace("/", ".")

    def resolve(self, topic_name: str) -> str:
        """Absolute topic name after ``-r from:=to`` remaps (relative names join the namespace)."""
        return self._ros_args.resolve(topic_name, self.namespace, self._given_name)

    @property
    def settings(self) -> wire.Settings:
        return self._p.settings

    # -- endpoints ---------------------------------------------------------------------
    def _make_writer(self, ros_name: str, ros_type: str, qos: QoS, dds_name: str | None = None,
                     cls: type | None = None, extra_ud: str = "", intra: bool = False) -> DdsPublisher:
        cls = cls or msgs.message_class(ros_type)
        dds_name = dds_name or wire.topic_name(self.resolve(ros_name))
        ud = wire.user_data_for_endpoint(ros_type, self._p.settings.distro, extra_ud)
        # the writer's history: the contract's writer_depth (a stalled reader's losses resent), readers keep depth
        w = DataWriter(self._p.dp, self._p.topic(dds_name, cls), qos=_qos(qos.for_writer(), ud, intra))
        gid = self._p.gid_of(w)
        self._writer_gids.append(gid)
        self._writer_topics.append((dds_name, gid16(gid)))
        self._p.publish_graph()
        if intra:
            return DdsPublisher(w, cls, self._ex.local_subscriptions(dds_name), self._ex.queue, gid16(gid))
        return DdsPublisher(w, cls, gid=gid16(gid))

    def _make_reader(self, dds_name: str, ros_type: str, cls: type, qos: QoS,
                     handler: Callable[[bytes, Any], None], extra_ud: str = "", intra: bool = False) -> DataReader:
        ud = wire.user_data_for_endpoint(ros_type, self._p.settings.distro, extra_ud)
        r = DataReader(self._p.dp, self._p.topic(dds_name, cls), qos=_qos(qos, ud, intra))
        self._ex.add_reader(r, handler, ReadCondition(r, ANY_SAMPLE), self)
        self._reader_gids.append(self._p.gid_of(r))
        self._p.publish_graph()
        return r

    @property
    def intra_process(self) -> bool:
        """True when topics between nodes of this node's executor bypass DDS (composition)."""
        return self._ex.intra_process

    def publisher(self, topic: Topic) -> DdsPublisher:
        return self._make_writer(topic.name, topic.type, topic.qos, intra=self._ex.intra_process)

    def _subscribe(self, topic: Topic, callback: Callable[[Any], object], raw: bool) -> None:
        cls = msgs.message_class(topic.type)
        resolved = self.resolve(topic.name)
        dds_name = wire.topic_name(resolved)
        intra = self._ex.intra_process
        what = f"subscription {resolved}"
        if intra:  # same-process publishers deliver through the executor's queue
            self._ex.local_subscriptions(dds_name).append(
                LocalSubscription(self, self._guard.wrap(what, callback), raw))
        if raw:
            handler = lambda data, info: callback(data)  # noqa: E731
        else:
            deser = fastcdr.decoder(cls)
            handler = lambda data, info: callback(deser(data))  # noqa: E731
        # a sample that does not decode or a callback that raises is counted and logged, never fatal
        self._make_reader(dds_name, topic.type, cls, topic.qos, self._guard.wrap(what, handler), intra=intra)

    def subscribe(self, topic: Topic, callback: Callable[[Any], object]) -> None:
        self._subscribe(topic, callback, raw=False)

    def subscribe_raw(self, topic: Topic, callback: RawCallback) -> None:
        """Deliver the CDR bytes as received (no decode): what rosbag2 stores."""
        self._subscribe(topic, callback, raw=True)

    def subscribe_with_source(self, topic: Topic, callback: SourcedCallback) -> None:
        """``callback(msg, writer_gid)``: the writer's GID from the sample's publication handle (remote)
        or from the publisher itself (intra-process); ``b""`` for a writer no longer matched."""
        cls = msgs.message_class(topic.type)
        resolved = self.resolve(topic.name)
        dds_name = wire.topic_name(resolved)
        intra = self._ex.intra_process
        what = f"subscription {resolved}"
        if intra:
            self._ex.local_subscriptions(dds_name).append(
                SourcedLocalSubscription(self, self._guard.wrap(what, lambda pair: callback(*pair)), False))
        deser = fastcdr.decoder(cls)
        gids: dict[int, bytes] = {}
        box: list[DataReader] = []

        def handler(data: bytes, info: Any) -> None:
            h = info.publication_handle
            gid = gids.get(h)
            if gid is None:
                try:
                    gid = gid16(box[0].get_matched_publication_data(h).key.bytes)
                except Exception:  # unmatched meanwhile (the writer left): no source to vouch for
                    gid = b""
                if gid:
                    if len(gids) >= _SOURCE_CACHE:
                        gids.clear()
                    gids[h] = gid
            callback(deser(data), gid)

        box.append(self._make_reader(dds_name, topic.type, cls, topic.qos, self._guard.wrap(what, handler),
                                     intra=intra))
        self._sourced.setdefault(dds_name, (box[0], gids))

    def publisher_gids(self, topic: Topic, node: str) -> frozenset[bytes]:
        """GIDs of ``node``'s live writers on ``topic``, joined with the writers ``node`` announces in
        ros_discovery_info: on a topic this node subscribes with source, the writers matched to that reader
        (a writer leaves the match when it is deleted or its participant's lease ends) and this process's own
        (matched or delivered in-process); otherwise the live writers of DCPSPublication."""
        dds_name = wire.topic_name(self.resolve(topic.name))
        fqn = node_fqn(node, self.namespace)
        src = self._sourced.get(dds_name)
        if src is None:
            return self._p.publisher_gids(dds_name, fqn)
        mine = self._p.node_writers(fqn)
        if not mine:
            return frozenset()
        reader, gids = src
        live = self._p.local_writers(dds_name)
        for h in reader.get_matched_publications():
            gid = gids.get(h)
            if gid is None:
                try:
                    gid = gid16(reader.get_matched_publication_data(h).key.bytes)
                except Exception:  # unmatched meanwhile
                    continue
                if len(gids) >= _SOURCE_CACHE:
                    gids.clear()
                gids[h] = gid
            live.add(gid)
        return frozenset(mine & live)

    def timer(self, period_s: float, callback: Callable[[], object]) -> DdsTimer:
        t = DdsTimer(period_s, self._guard.wrap(f"timer {period_s:g} s", callback), self)
        self._ex.add_timer(t)
        return t

    @property
    def callback_errors(self) -> dict[str, int]:
        """Exceptions raised by this node's callbacks so far, per callback name (a copy)."""
        return dict(self._guard.errors)

    def now_ns(self) -> int:
        return time.time_ns()

    def msg(self, type_name: str) -> type:
        return msgs.message_class(type_name)

    # -- dispatch ------------------------------------------------------------------------
    def spin_once(self, timeout_s: float | None = 0.1) -> None:
        """Wait for data, a timer deadline or ``timeout_s``; then run what is ready (on this node's executor)."""
        if not self._shutdown:
            self._ex.spin_once(timeout_s)

    def spin(self) -> None:
        """Dispatch until :meth:`shutdown` (waits are bounded so signals are handled)."""
        while not self._shutdown:
            self._ex.spin_once(None)

    def shutdown(self) -> None:
        """Stop spinning, leave the graph, release the participant with the last node; idempotent."""
        if self._shutdown:
            return
        self._shutdown = True
        self._ex.wake()
        # entities go once no spin_once runs (deferred when called from a callback or a signal handler)
        self._ex.remove_node(self, lambda: self._p.remove_node(self))

    @property
    def is_shutdown(self) -> bool:
        return self._shutdown

    # -- parameters ----------------------------------------------------------------------
    def declare_parameters(self, group: str, on_change: OnChange | None = None) -> dict[str, Any]:
        """Declare the schema group as ROS parameters; serve the rcl_interfaces services.

        Start values: schema defaults <- ``--params-file`` <- ``-p``, validated
        (ConfigError on a bad file or value). Returns the validated dict.
        """
        if self._params is not None:
            raise TransportError(f"{self.fully_qualified_name}: parameters already declared "
                                 f"(group {self._params.group!r})")
        values = initial_parameters(group, self._ros_args, self.name, strict=not self._ignore_undeclared)
        self._params = ParameterStore(group, values, on_change)
        for srv, (srv_type, req_cls, rep_cls) in msgs.SERVICES.items():
            self._serve(srv, srv_type, req_cls, rep_cls, getattr(self, "_srv_" + srv))
        self._announce(new=list(values))
        return dict(values)

    @property
    def parameters(self) -> dict[str, Any]:
        """Current parameter values (a copy)."""
        return self._params.values if self._params is not None else {}

    def set_parameters(self, changes: Mapping[str, Any]) -> str | None:
        """Apply ``changes`` atomically, as an external client would; ``None`` or the rejection reason."""
        return self._try_set(dict(changes))

    def _try_set(self, changes: dict[str, Any]) -> str | None:
        if self._params is None:
            return "no parameters declared"
        reason = self._params.set(changes, self.fully_qualified_name)
        if reason is None:
            self._announce(changed=list(changes))
        return reason

    def _param_msg(self, name: str) -> Any:
        assert self._params is not None
        spec = self._params.specs[name]
        return msgs.Parameter(name=name,
                              value=pv.to_value_msg(msgs.ParameterValue, self._params[name], pv.spec_type(spec)))

    def _announce(self, new: list[str] = (), changed: list[str] = ()) -> None:  # type: ignore[assignment]
        t = time.time_ns()
        self._events_pub.publish(msgs.ParameterEvent(
            stamp=msgs.Time(sec=t // 10**9, nanosec=t % 10**9),
            node=self.fully_qualified_name,
            new_parameters=[self._param_msg(n) for n in new],
            changed_parameters=[self._param_msg(n) for n in changed],
            deleted_parameters=[],
        ))

    # -- services ------------------------------------------------------------------------
    def service(self, name: str, srv_type: str, callback: ServiceCallback) -> None:
        """Serve ``<node>/<name>`` (``std_srvs/srv/Trigger`` or ``SetBool``): ``callback(request, response)``.

        A callback that raises answers ``success = False`` with the exception as the message
        (counted and logged once like any callback error); one that returns None answers the
        response object it was given.
        """
        req_cls, rep_cls = srvs.service_classes(srv_type)
        what = f"service {self.fully_qualified_name.rstrip('/')}/{name.strip('/')}"
        guard = self._guard

        def compute(req: Any, rep: Any) -> None:
            out = guard.answer(what, callback, req, rep)
            if out is not rep:
                for f in ("success", "message"):
                    setattr(rep, f, getattr(out, f))

        self._serve(name.strip("/"), srv_type, req_cls, rep_cls, compute)

    def serve_lifecycle(self, machine: LifecycleMachine) -> None:
        """The managed-node services and ``~/transition_event`` with the IDL types of :mod:`.lifecycle_msgs`;
        ``~/change_state``'s reply is queued when the transition ends (:meth:`flush_replies` sends it)."""
        iface = LifecycleInterface(machine, State=lifecycle_msgs.State, Transition=lifecycle_msgs.Transition,
                                   TransitionDescription=lifecycle_msgs.TransitionDescription,
                                   TransitionEvent=lifecycle_msgs.TransitionEvent, log=self.logger.warn)
        topic = event_topic(self.fully_qualified_name)
        events = self._make_writer(topic.name, topic.type, topic.qos, cls=lifecycle_msgs.TransitionEvent)
        machine.listeners.append(lambda e: events.publish(iface.event(e)))
        for srv, srv_type in lifecycle_msgs.SERVICES.items():
            req_cls, rep_cls = lifecycle_msgs.SERVICE_CLASSES[srv_type]
            self._serve(srv, srv_type, req_cls, rep_cls, getattr(iface, srv), deferred=srv == "change_state")

    def _serve(self, srv: str, srv_type: str, req_cls: Any, rep_cls: Any, compute: Callable[..., Any],
               deferred: bool = False) -> None:
        """Serve ``<node>/<srv>``: ``compute(request, response)`` fills the response, which is then sent; with
        ``deferred``, ``compute(request, response, send)`` calls ``send()`` itself, now or later (on this
        node's executor thread)."""
        rq, rr = wire.service_topics(self.fully_qualified_name + "/" + srv)
        self._csid += 1
        gid = self._p.gid
        csid = ".".join(f"{b:x}" for b in gid[:12]) + f".{self._csid:x}"
        ud = f"serviceid={csid};"
        writer = self._make_writer("", srv_type + "_Response", QOS_SERVICES, dds_name=rr, cls=rep_cls, extra_ud=ud)
        reader_box: list[DataReader] = []

        def handle(data: bytes, info: Any) -> None:
            req = req_cls.deserialize(data)
            rep = rep_cls(guid=req.guid, seq=req.seq)
            clientid = _user_data_key(reader_box[0], info.publication_handle, "clientid")

            def send() -> None:
                payload = rep.serialize()
                payload += b"\0" * (-len(payload) % 4)
                # wait for the client's reader to match (rmw_cyclonedds: 100 ms; a busy 1 kHz node needs longer)
                self._pending_replies.append((time.monotonic_ns() + 5_000_000_000, writer, payload, clientid))
                self.flush_replies()

            if deferred:
                compute(req, rep, send)
            else:
                compute(req, rep)
                send()

        handler = self._guard.wrap(f"service {self.fully_qualified_name}/{srv}", handle)
        reader_box.append(self._make_reader(rq, srv_type + "_Request", req_cls, QOS_SERVICES, handler, extra_ud=ud))

    @property
    def has_pending_replies(self) -> bool:
        """Replies wait for their client's reader to match (the executor polls again within 5 ms)."""
        return bool(self._pending_replies)

    def flush_replies(self) -> None:
        """Send replies whose client reader is matched (rmw_cyclonedds waits up to 100 ms for that)."""
        now = time.monotonic_ns()
        keep = []
        for deadline, pub, payload, clientid in self._pending_replies:
            if not clientid or now >= deadline or _has_reader_with(pub.writer, clientid):
                ddspy_write(pub.ref, payload)  # (a reply that cannot be written is the client's timeout)
            else:
                keep.append((deadline, pub, payload, clientid))
        self._pending_replies = keep

    @property
    def _specs(self) -> dict[str, Any]:
        return self._params.specs if self._params is not None else {}

    def _srv_get_parameters(self, req: Any, rep: Any) -> None:
        store = self._params
        rep.values = [
            pv.to_value_msg(msgs.ParameterValue, store[n], pv.spec_type(store.specs[n]))
            if store is not None and n in store else msgs.ParameterValue()
            for n in req.names
        ]

    def _srv_get_parameter_types(self, req: Any, rep: Any) -> None:
        rep.types = [pv.spec_type(self._specs[n]) if n in self._specs else pv.NOT_SET for n in req.names]

    def _srv_list_parameters(self, req: Any, rep: Any) -> None:
        names = sorted(self._specs)
        if req.prefixes:
            names = [n for n in names if any(n == p or n.startswith(p + ".") for p in req.prefixes)]
        rep.result = msgs.ListParametersResult(names=names, prefixes=[])

    def _srv_describe_parameters(self, req: Any, rep: Any) -> None:
        out = []
        for n in req.names:
            if n in self._specs:
                out.append(pv.describe(self._specs[n], msgs.ParameterDescriptor, msgs.FloatingPointRange,
                                       msgs.IntegerRange))
            else:
                out.append(msgs.ParameterDescriptor(name=n))
        rep.descriptors = out

    def _try_set_msgs(self, parameters: Any) -> str | None:
        """Apply rcl_interfaces/msg/Parameter messages atomically: None, or why not (a value of an unknown type
        included: every request gets an answer with its reason)."""
        try:
            changes = {p.name: pv.from_value_msg(p.value) for p in parameters}
        except ValueError as exc:
            return str(exc)
        return self._try_set(changes)

    def _srv_set_parameters(self, req: Any, rep: Any) -> None:
        # like rclpy: each parameter is set on its own (use set_parameters_atomically for several)
        results = []
        for p in req.parameters:
            reason = self._try_set_msgs([p])
            results.append(msgs.SetParametersResult(successful=reason is None, reason=reason or ""))
        rep.results = results

    def _srv_set_parameters_atomically(self, req: Any, rep: Any) -> None:
        reason = self._try_set_msgs(req.parameters)
        rep.result = msgs.SetParametersResult(successful=reason is None, reason=reason or "")


def _qos(qos: QoS, user_data: bytes, ignore_local: bool) -> Any:
    """The DDS QoS of an endpoint; intra-process endpoints ignore their own participant."""
    q = wire.dds_qos(qos, user_data)
    if ignore_local:
        from cyclonedds.qos import Policy, Qos

        q += Qos(Policy.IgnoreLocal.Participant)
    return q


def _user_data(qos: Any) -> bytes:
    from cyclonedds.qos import Policy

    try:
        return bytes(qos[Policy.Userdata].data)
    except Exception:
        return b""


def _parse_user_data(ud: bytes) -> dict[str, str]:
    out = {}
    for item in ud.decode(errors="replace").split(";"):
        k, sep, v = item.partition("=")
        if sep:
            out[k] = v
    return out


def _user_data_key(reader: DataReader, pub_handle: int, key: str) -> str:
    try:
        ep = reader.get_matched_publication_data(pub_handle)
    except Exception:
        return ""
    if ep is None:
        return ""
    return _parse_user_data(_user_data(ep.qos)).get(key, "")


def _has_reader_with(writer: DataWriter, clientid: str) -> bool:
    for h in writer.get_matched_subscriptions():
        try:
            ep = writer.get_matched_subscription_data(h)
        except Exception:
            continue
        if ep is not None and _parse_user_data(_user_data(ep.qos)).get("clientid") == clientid:
            return True
    return False
