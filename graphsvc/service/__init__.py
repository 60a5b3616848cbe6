"""The graphsvc.v1 gRPC service: server, client, serial sensor bridge.

server.py    the MotionGraphService, health, reflection, auth, TLS, `graphsvc serve`
client.py    connections and calls, used by `graphsvc client ...` and the bridge
bridge.py    serial line protocol → live stream (`graphsvc sensor-bridge`)
convert.py   protos ↔ numpy arrays, Recording, Motion, pipeline Options
_generated/  stubs from proto/graphsvc/v1/graphsvc.proto (tools/gen_proto.py)
"""
