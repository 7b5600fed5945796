"""Test configuration: float64 and strict rank promotion for the whole suite.

XLA's CPU backend spends most of this suite's time compiling (the programs run in
milliseconds), so unless XLA_FLAGS already chooses a backend optimisation level we
compile with `--xla_backend_optimization_level=0`: it halves compile time and does not
change the floating-point semantics (no fast-math either way). Set
OCP_TEST_XLA_DEFAULT_OPT=1 to test with XLA's default optimisation level.

Compiled functions are shared within a test module (helpers.batched and the modules'
`functools.cache` functions); every compiled program is dropped after each module (see
`_release_compiled_programs`). The README's command runs the suite on every core with
pytest-xdist's `--dist worksteal`: each worker starts with an even share of the collection
in order (whole modules, mostly) and an idle worker takes tests from the end of the
other's queue, so little compilation is repeated. `-n 0` runs it in one process.
"""

import gc
import os
import shutil
import sys
import tempfile

if not os.environ.get("OCP_TEST_XLA_DEFAULT_OPT") and "xla_backend_optimization_level" not in (
    os.environ.get("XLA_FLAGS", "")
):
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0"
    ).strip()

# the CLI's tests run in this process: no cache of the CLI's own there
os.environ.setdefault("OCP_JAX_CACHE_DIR", "off")
# One persistent compilation cache for the whole run, shared by the xdist workers and the
# notebooks' kernels (they inherit the environment): a program that several test modules
# or processes compile (each module drops its programs, see below) is compiled once.
_CACHE_CREATED_HERE = "JAX_COMPILATION_CACHE_DIR" not in os.environ
if _CACHE_CREATED_HERE:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="ocp_jax_tests_")
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    os.environ["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"] = "0"

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import helpers  # noqa: E402
import pytest  # noqa: E402


def pytest_report_header(config):
    return [
        f"jax {jax.__version__}, x64, rank promotion 'raise', "
        f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}"
    ]


@pytest.fixture(scope="session")
def reference_specs():
    """The NumPy reference's curve specs of every named test scene."""
    return {name: helpers.to_reference(scene) for name, scene in helpers.SCENES.items()}


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    """Drop every compiled program after each test module. A whole-suite process
    otherwise holds hundreds of XLA executables (6.7 GB), and XLA crashed compiling the
    last module (an abort, then a segfault, in two runs; each module passes alone)."""
    yield
    jax.clear_caches()
    gc.collect()


def pytest_unconfigure(config):
    """The process that made the run's compilation cache removes it at the end."""
    if _CACHE_CREATED_HERE:
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)
