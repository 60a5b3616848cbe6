"""Stubs generated from proto/graphsvc/v1/graphsvc.proto by tools/gen_proto.py.
Do not edit; regenerate (tests/service/test_generated.py checks they are current)."""
