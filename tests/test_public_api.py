"""The public API (`graphsvc.__all__`): every name resolves to the object its module
defines, lazily (importing `graphsvc` imports none of those modules), and the Python
API guide (docs/python-api.md, itself run as doctests) uses no other name of the
package's top level."""

import importlib
import inspect
import re
import subprocess
import sys

import pytest

import graphsvc
from tests.conftest import ROOT


def test_every_public_name_resolves_to_its_modules_object():
    assert len(set(graphsvc.__all__)) == len(graphsvc.__all__)
    for name in graphsvc.__all__:
        module = importlib.import_module(graphsvc._API[name])
        assert getattr(graphsvc, name) is getattr(module, name), name
    namespace: dict = {}
    exec("from graphsvc import *", namespace)
    assert set(graphsvc.__all__) <= set(namespace)
    assert set(graphsvc.__all__) <= set(dir(graphsvc))


def test_the_public_functions_carry_type_hints():
    functions = [getattr(graphsvc, n) for n in graphsvc.__all__ if inspect.isfunction(getattr(graphsvc, n))]
    functions += [graphsvc.LiveSession.push, graphsvc.LiveSession.flush, graphsvc.LiveSession.motion]
    assert len(functions) > 20
    for f in functions:
        sig = inspect.signature(f)
        bare = [p.name for p in sig.parameters.values() if p.annotation is inspect.Parameter.empty and p.name != "self"]
        assert not bare and sig.return_annotation is not inspect.Signature.empty, (f.__qualname__, bare)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        graphsvc.no_such_name  # noqa: B018
    with pytest.raises(ImportError):
        exec("from graphsvc import no_such_name", {})


def test_importing_the_package_imports_none_of_the_api():
    code = (
        "import sys, graphsvc; print(' '.join(sorted(m for m in sys.modules if m.startswith('graphsvc')))); "
        "graphsvc.Options; print('graphsvc.strategies.options' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0].split() == ["graphsvc", "graphsvc.kernel_cache", "graphsvc.numba_env"]
    assert out[1] == "True"  # (and a name, once used, brings its module)


def test_the_guide_uses_only_public_names():
    lines = (ROOT / "docs" / "python-api.md").read_text(encoding="utf-8").splitlines()
    code = "\n".join(s[4:] for s in (line.strip() for line in lines) if s.startswith((">>> ", "... ")))
    used = set(re.findall(r"\bgraphsvc\.(\w+)", code))
    used |= {n.strip() for names in re.findall(r"from graphsvc import ([\w, ]+)", code) for n in names.split(",")}
    assert used <= set(graphsvc.__all__), sorted(used - set(graphsvc.__all__))
    assert {
        "load_motion",
        "build_graph",
        "simulate_recording",
        "reconstruct",
        "run_leave_one_out",
        "open_session",
    } <= used
