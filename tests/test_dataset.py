"""batch_loader: the same batches as a plain DataLoader, read a batch at a time."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from tactile_compliance.data.dataset import GraspDataset, batch_loader
from tactile_compliance.data.normalisation import NormalisationConstants
from toy_store import make_toy_store


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("toy") / "store")


@pytest.mark.parametrize("cached", [False, True])
@pytest.mark.parametrize("shuffle", [False, True])
def test_batch_loader_equals_per_sample_collation(toy_store, cached, shuffle):
    ids = np.array([3, 1, 4, 1, 5, 9, 2, 6, 5, 3])  # repeats, like balanced sampling
    features = None
    if cached:
        rng = np.random.default_rng(0)
        features = rng.standard_normal((len(toy_store), 3, 8)).astype(np.float16)
    dataset = GraspDataset(toy_store, ids, NormalisationConstants(), "ALL", features)
    torch.manual_seed(0)
    plain = list(DataLoader(dataset, batch_size=4, shuffle=shuffle))
    torch.manual_seed(0)
    batched = list(batch_loader(dataset, 4, shuffle=shuffle))
    assert [len(b["label"]) for b in batched] == [4, 4, 2]
    assert len(plain) == len(batched)
    for a, b in zip(plain, batched, strict=True):
        assert a.keys() == b.keys()
        for key in a:
            assert a[key].dtype == b[key].dtype, key
            assert torch.equal(a[key], b[key]), key
