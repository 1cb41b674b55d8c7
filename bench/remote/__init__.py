"""Policies from other stacks: openpi's websocket policy-server protocol, both ends.

    wire       msgpack-numpy frames as openpi encodes them; decoding never unpickles
    obs_map    `obs_map=` entries: which observation entries a server gets, under which names
    latency    per-episode round-trip statistics and their pooling over a run
    client     `policy=remote` (the PolicyPlugin) and its connection
    server     `bench serve`: any bench policy behind the protocol

docs/remote-policies.md has the protocol, the keys, openpi/lerobot recipes and the latency semantics.
"""
