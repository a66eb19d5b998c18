"""matchers/weights.py's loader on toy modules and a toy weight file: derived buffers may be
persistent (kornia < 0.9.2 kept ALIKED's ``dkd.hw_grid`` in the state dict) or not (since 0.9.2);
a declared derived buffer the module does not have at all, a missing parameter or a file key
without a slot is an error naming it."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from matchers.weights import BundledWeights, WeightLoadError, load_bundled  # noqa: E402


class Toy(torch.nn.Module):
    def __init__(self, persistent: bool):
        super().__init__()
        self.linear = torch.nn.Linear(2, 2)
        self.register_buffer("grid", torch.arange(4.0), persistent=persistent)


@pytest.fixture
def weights(tmp_path, monkeypatch):
    """A toy package folder with a file that carries the parameters only."""
    folder = tmp_path / "toy_weights"
    folder.mkdir()
    source = Toy(True)
    torch.save({"linear.weight": torch.full((2, 2), 3.0), "linear.bias": torch.ones(2)}, folder / "w.pth")
    monkeypatch.syspath_prepend(str(tmp_path))
    (folder / "__init__.py").write_text("")
    assert source.grid.shape == (4,)
    return lambda **kw: BundledWeights("toy_weights", "w.pth", **kw)


@pytest.mark.parametrize("persistent", [True, False])
def test_a_derived_buffer_persistent_or_not_keeps_the_module_s_value(weights, persistent):
    module = Toy(persistent)
    load_bundled(module, weights(derived_buffers=("grid",)))
    assert torch.equal(module.linear.weight, torch.full((2, 2), 3.0))
    assert torch.equal(module.grid, torch.arange(4.0))


def test_a_declared_derived_buffer_that_is_no_buffer_is_an_error(weights):
    with pytest.raises(WeightLoadError, match="declared derived buffers not in the module: gird"):
        load_bundled(Toy(False), weights(derived_buffers=("grid", "gird")))


def test_an_undeclared_persistent_buffer_is_missing_in_the_file(weights):
    with pytest.raises(WeightLoadError, match="missing in the file: grid"):
        load_bundled(Toy(True), weights())
    load_bundled(Toy(False), weights())  # a non-persistent one is not the file's business
