"""A pytest plugin that says where the test-suite's time goes: per test module, the wall
time of its tests and the seconds JAX spent tracing, lowering and compiling (XLA) in
them, with the number of compilations (those answered by the persistent cache count as
compilations here).

    PYTHONPATH=dev python -m pytest -q -n 2 --dist worksteal -p suite_profile tests

Works with pytest-xdist: each test's figures travel in its teardown report's
`user_properties`.
Notebooks and other subprocesses are counted as wall time only.
"""

import collections
import time

import jax.monitoring
import pytest

_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}
_current: collections.Counter | None = None
_start = 0.0
_modules: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)


def _record(event: str, duration: float, **_):
    if _current is not None and event in _EVENTS:
        _current[_EVENTS[event]] += duration
        if _EVENTS[event] == "compile":
            _current["compilations"] += 1


jax.monitoring.register_event_duration_secs_listener(_record)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    global _current, _start
    _current, _start = collections.Counter(), time.perf_counter()
    yield
    _current = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    if call.when == "teardown" and _current is not None:  # (before the report is made)
        _current["wall"] = time.perf_counter() - _start
        item.user_properties.append(("suite_profile", dict(_current)))
    yield


def pytest_runtest_logreport(report):
    for name, counts in report.user_properties:
        if name == "suite_profile" and report.when == "teardown":
            _modules[report.nodeid.split("::")[0]].update(counts)


def pytest_terminal_summary(terminalreporter):
    columns = ("wall", "trace", "lower", "compile", "compilations")
    terminalreporter.write_sep("=", "time per test module (seconds)")
    terminalreporter.write_line(f"{'module':42s}" + "".join(f"{c:>14s}" for c in columns))
    total = collections.Counter()
    rows = sorted(_modules.items(), key=lambda item: -item[1]["wall"])
    for module, counts in [*rows, ("all", total)]:
        if module != "all":
            total.update(counts)
        figures = "".join(f"{counts[c]:14.0f}" for c in columns)
        terminalreporter.write_line(f"{module:42s}{figures}")
