"""A minimal Foxglove WebSocket client for the tests (subprotocol ``foxglove.sdk.v1``)."""
from __future__ import annotations

import asyncio
import json
import struct

import websockets

from dmf_sim.live.foxglove_bridge import SUBPROTOCOL

TIMEOUT_S = 10.0


async def _first(url: str, topic: str) -> tuple[dict[str, str], int, bytes]:
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as ws:
        channels = {}
        while topic not in channels:
            msg = json.loads(await asyncio.wait_for(ws.recv(), TIMEOUT_S))
            if msg['op'] == 'advertise':
                channels.update({c['topic']: c for c in msg['channels']})
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': 1, 'channelId': channels[topic]['id']}]}))
        while True:
            data = await asyncio.wait_for(ws.recv(), TIMEOUT_S)
            if isinstance(data, bytes) and data[0] == 0x01:        # Message Data
                log_time = struct.unpack_from('<Q', data, 5)[0]
                return {t: c['schemaName'] for t, c in channels.items()}, log_time, data[13:]


def first_message(url: str, topic: str) -> tuple[dict[str, str], int, bytes]:
    """Connect, subscribe to ``topic``: every advertised channel (topic -> schema name), and
    the log time [ns] and CDR payload of the first message received after subscribing."""
    return asyncio.run(_first(url, topic))
