"""The graphsvc.v1 gRPC service: server, client, serial sensor bridge, VMC output.

server.py        bind, start, run and stop the server (`graphsvc serve`): TLS, health,
                 reflection, the drain after SIGTERM
servicer.py      the MotionGraphService's handlers (graphs, Synthesize, streams, batches)
graphs.py        the graphs a server serves, loaded once (`--graph NAME=FILE`)
streams.py       a live stream's slot, its first message and what its config announces
interceptors.py  the call gate (loading, serving, draining) and bearer-token auth
status.py        failures → gRPC status codes and details
live_workers.py  live sessions in worker processes
metrics.py       Prometheus metrics (`serve --metrics-port`) and the refusals' counter
client.py        connections and calls, used by `graphsvc client ...` and the bridge
servers.py       several servers behind one channel (`--server A,B`, round_robin), probed
bridge.py        serial line protocol → live stream (`graphsvc sensor-bridge`)
vmc.py           pose frames out to animation tools over VMC (OSC/UDP; `--vmc`)
convert.py       protos ↔ graphsvc's objects, every conversion re-exported from:
  convert_graph.py      Skeleton, GraphInfo
  convert_recording.py  Recording, a stream's samples and marker names, sensor order
  convert_motion.py     Motion, PoseFrame, Provenance
  convert_report.py     reports, BatchStatus, Struct values
  options_proto.py      the pipeline's Options
_generated/      stubs from proto/graphsvc/v1/graphsvc.proto (tools/gen_proto.py)
"""
