"""Session-wide fixtures: synthetic models, the shipped open body model and mocap clips; nothing here needs a
licensed file or a download."""

import numpy as np
import pytest
from m3c.body import BodyModel
from m3c.body.synthetic import make_synthetic_model


@pytest.fixture(scope="session")
def synthetic_model_data():
    return make_synthetic_model(vertices_per_bone=24, num_betas=10, seed=0)


@pytest.fixture(scope="session")
def synthetic_body_model(synthetic_model_data):
    return BodyModel(synthetic_model_data)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(autouse=True, scope="session")
def _pipeline_test_nodes():
    """Registers M3C's built-in node types and the framework tests' own (tests/python/pipeline_test_nodes.py), as
    the m3c command registers the built-in ones."""
    import pipeline_test_nodes  # noqa: F401
    from m3c.nodes import register_builtin_nodes

    register_builtin_nodes()


@pytest.fixture(scope="module")
def one_torch_thread():
    """Torch on one thread for a test module: networks run as many small ops, and with the cores shared by other
    jobs, OpenMP's spin-waiting at every op makes two threads several times slower than one."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def open_model():
    """M3C's shipped open body model."""
    from m3c.body import default_body_model

    return default_body_model()


@pytest.fixture(scope="session")
def mocap_clips():
    """The shipped retargeted CMU clips of the benchmarks."""
    from m3c.eval.benchmark import load_clips

    return load_clips()
