"""Fuzzing every reader: the table of targets (`targets`), their procedural seed
corpus (`seeds`), the mutation engine (`mutate`) and the one-input runner that tells
an accepted or refused input from a finding (`run`). The test suite runs a short
pass (tests/test_fuzz.py); `tools/fuzz.py` runs long ones. See docs/fuzzing.md."""
