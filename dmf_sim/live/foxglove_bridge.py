"""Serve the node's streams over the Foxglove WebSocket protocol (``foxglove-sdk``), no bridge.

``FoxgloveBridge({topic: ROS type}, port=8765)`` starts a Foxglove WebSocket server (the SDK's
server: subprotocol ``foxglove.sdk.v1``) with one channel per topic: message encoding ``cdr``,
schema encoding ``ros2msg`` with the full message definition (as in the node's MCAP bags), so
Foxglove decodes the bytes as the ROS 2 messages they are and the layout's message paths work the
same on this connection, on a ROS bridge and on a recorded bag. :meth:`FoxgloveBridge.publish`
takes the CDR bytes the node already serialized for DDS and the bag, with the sample's stamp as
log time; it costs a channel lookup and, while no client subscribes to the channel, nothing
more. Each bridge has its own SDK context, so several can run in one process.

Latched topics (``latched``: the node's transient-local streams, the prediction): the bridge
keeps the last message of each and sends it to a client as soon as it subscribes, as DDS does
for a late transient-local subscriber; so a viewer that connects after the prediction shows it
at once, not only after the next setpoint change. (The SDK logs to every subscribed client of
the channel; a client that was already subscribed receives the latest value once more.)

The node enables it with ``-p foxglove_port:=8765`` (0 = off, the default); ``foxglove_host``
(default 127.0.0.1; 0.0.0.0 to serve other machines) and logs the server's URL at start.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.optional import require

__all__ = ['SUBPROTOCOL', 'FOXGLOVE_PARAMETERS', 'LAYOUT_FILE', 'FoxgloveBridge', 'foxglove_hint',
           'foxglove_layout', 'message_definition']

SUBPROTOCOL = 'foxglove.sdk.v1'      # what the SDK's server accepts (checked by the tests)
SERVER_NAME = 'dmf_sim'
LAYOUT_FILE = 'foxglove_layout.json'     # in config/: the layout of a node named /driveline_node
DEFAULT_NODE = '/driveline_node'

# Node parameters: name -> (default, description, (lo, hi) or None). Read-only (start-up).
FOXGLOVE_PARAMETERS: dict[str, tuple] = {
    'foxglove_port': (0, 'Serve the streams over the Foxglove WebSocket protocol on this TCP '
                      'port (0 = off)', (0, 65535)),
    'foxglove_host': ('127.0.0.1', 'Address the Foxglove server listens on (0.0.0.0: every '
                      'interface)', None),
}


def message_definition(msgtype: str) -> str:
    """ros2msg definition text of a ROS 2 Jazzy type with its dependencies (rosbag2 style)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    try:
        return store.generate_msgdef(msgtype, ros_version=2)[0]
    except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds for unknown types
        raise ConfigError(f'foxglove: unknown message type {msgtype!r} ({exc})') from None


class FoxgloveBridge:
    """A Foxglove WebSocket server for given ROS topics (see the module docstring).

    Args:
        streams: absolute topic name -> ROS type name (e.g. ``'std_msgs/msg/Float64'``).
        host, port: where to listen (port 0: any free port, see :attr:`port`).
        name: server name shown by Foxglove.
        latched: topics whose last message a client gets when it subscribes.
    """

    def __init__(self, streams: Mapping[str, str], *, host: str = '127.0.0.1', port: int = 8765,
                 name: str = SERVER_NAME, latched: Iterable[str] = ()) -> None:
        foxglove = require('foxglove')
        ServerListener = require('foxglove.websocket').ServerListener

        if not (isinstance(port, int) and 0 <= port <= 65535):
            raise ConfigError(f'foxglove_port must be in 0..65535, got {port!r}')
        self._context = foxglove.Context()
        self._channels = {}
        for topic, msgtype in streams.items():
            if not topic.startswith('/'):
                raise ConfigError(f'foxglove: topic names must be absolute, got {topic!r}')
            schema = foxglove.Schema(name=msgtype, encoding='ros2msg',
                                     data=message_definition(msgtype).encode())
            self._channels[topic] = foxglove.Channel(topic, schema=schema,
                                                     message_encoding='cdr',
                                                     context=self._context)
        if unknown := set(latched) - set(self._channels):
            raise ConfigError(f'foxglove: latched topics {sorted(unknown)} are not streams')
        #: latched topic -> (log time [ns], CDR bytes) of its last message
        self._latest: dict[str, tuple[int, bytes]] = {}
        self._latched = frozenset(latched)
        bridge = self

        class _Listener(ServerListener):
            def on_subscribe(self, client, channel) -> None:
                bridge._resend(channel.topic)

        try:
            self._server = foxglove.start_server(name=name, host=host, port=port,
                                                 context=self._context,
                                                 server_listener=_Listener())
        except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError for bind errors
            raise ConfigError(f'foxglove server on {host}:{port}: '
                              f'{" ".join(str(exc).split())}') from None
        self.host = host

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        return f'ws://{self.host}:{self.port}'

    def publish(self, topic: str, data: bytes, stamp_ns: int) -> None:
        """Send one CDR-serialized message of ``topic`` (log time ``stamp_ns``) to the clients
        subscribed to it (nothing when none is)."""
        ch = self._channels.get(topic)
        if ch is None:
            return
        if topic in self._latched:
            self._latest[topic] = (int(stamp_ns), bytes(data))
        ch.log(bytes(data), log_time=int(stamp_ns))

    def _resend(self, topic: str) -> None:
        """A client subscribed to ``topic`` (server thread): send it the latched message."""
        if (last := self._latest.get(topic)) is not None:
            self._channels[topic].log(last[1], log_time=last[0])

    def has_subscribers(self, topic: str) -> bool:
        ch = self._channels.get(topic)
        return ch is not None and ch.has_sinks()

    def close(self) -> None:
        """Stop the server (clients are disconnected)."""
        self._server.stop()
        for ch in self._channels.values():
            ch.close()


def foxglove_hint(url: str, node: str) -> str:
    """The node's start-up line about its Foxglove server: where, and which layout."""
    layout = (f'config/{LAYOUT_FILE}' if node == DEFAULT_NODE else
              f'`dmf-sim monitor --node {node} --foxglove-layout layout.json`')
    return (f'Foxglove server at {url} (Foxglove: Open connection > Foxglove WebSocket > {url}; '
            f'import the layout {layout})')


def foxglove_layout(node: str = DEFAULT_NODE) -> dict:
    """The shipped Foxglove layout (``config/foxglove_layout.json``, written for the node
    ``/driveline_node``) for the node whose fully qualified name is ``node``: its namespaced
    topics in every message path, and its health status selected by the hardware id it
    publishes (its full name) in the Diagnostic Status panel and the ``$node`` variable.

    Foxglove's Diagnostic Status panel shows one hardware id and cannot take a variable, so a
    namespaced node needs this rewritten layout (``dmf-sim monitor --node NAME
    --foxglove-layout FILE``);
    the Diagnostics Summary panel lists every node's statuses anyway."""
    import json

    from dmf_sim.core.paths import config_dir, read_text
    from dmf_sim.live.streams import streams_for
    from dmf_sim.physics.model import read_driveline

    fqn = '/' + node.strip().strip('/')
    if fqn == '/' or any(not part.replace('_', 'a').isalnum() for part in fqn[1:].split('/')):
        raise ConfigError(f'node {node!r} must be a fully qualified ROS node name like '
                          '/truck1/driveline_node')
    ns = fqn.rsplit('/', 1)[0]
    layout = json.loads(read_text(config_dir() / LAYOUT_FILE))
    # the layout shows the default driveline's sensors (the node's default, read_driveline's
    # too): their topics move with the others
    streams = streams_for(read_driveline().sensors)
    relative = tuple('/' + s.topic for s in streams.values() if not s.topic.startswith('/'))

    def move(path: str) -> str:
        for topic in relative:
            if path == topic or path.startswith(topic + '.'):
                return ns + path
        return path

    for pid, cfg in layout['configById'].items():
        for item in cfg.get('paths', ()):
            item['value'] = move(item['value'])
        for key in ('topicPath', 'topicToRender'):
            if key in cfg:
                cfg[key] = move(cfg[key])
        if pid.startswith('DiagnosticStatusPanel'):
            cfg['selectedHardwareId'] = fqn
    layout['globalVariables']['node'] = fqn
    return layout
