"""Marginalisation of the window's oldest keyframe: :func:`marginalise_factors`.

The keyframe's projection factors are dropped by the window (their landmarks keep their
other observations; OKVIS-style, to keep the graph sparse). Its other factors (motion
factors, priors, earlier marginals) are either dropped (a source whose keyframes each
carry their own priors) or eliminated into a linear marginal factor on the keys they
share with the rest of the window (``LinearContainerFactor``): the information of a chain
of motion factors is kept, and memory stays bounded by the window.
"""

from __future__ import annotations

from vio_core.errors import NumericalError


def subset_values(values, keys):
    """A copy of ``gtsam.Values`` ``values`` restricted to the gtsam ``keys`` (any value types)."""
    import gtsam

    out = gtsam.Values(values)
    wanted = set(keys)
    for k in list(out.keys()):
        if k not in wanted:
            out.erase(k)
    return out


def marginalise_factors(factors: list, values, old_keys, keep: bool) -> list:
    """The non-visual factors once the keys ``old_keys`` are marginalised.

    Args:
        factors: ``[(frozenset of keys, gtsam factor)]``, the window's non-visual factors.
        values: ``gtsam.Values``, the linearisation point (the window's current estimate).
        old_keys: gtsam keys of the marginalised keyframe (pose and the source's extra keys).
        keep: eliminate the factors touching ``old_keys`` into linear marginal factors
            (True) or drop them (False).

    Returns:
        The factors not touching ``old_keys``, then the marginal factors (same form).

    Raises:
        NumericalError: the elimination failed (e.g. an indeterminant system): the window is
            then unusable.
    """
    import gtsam

    old = set(old_keys)
    touching = [(k, f) for k, f in factors if k & old]
    out = [(k, f) for k, f in factors if not k & old]
    if not touching or not keep:
        return out
    graph = gtsam.NonlinearFactorGraph()
    for _, f in touching:
        graph.add(f)
    keys = set().union(*(k for k, _ in touching))
    try:
        linear = graph.linearize(subset_values(values, sorted(keys)))
        ordering = gtsam.Ordering()
        for k in sorted(old & keys):
            ordering.push_back(k)
        _, remaining = linear.eliminatePartialSequential(ordering)
    except RuntimeError as exc:  # gtsam: indeterminant linear system and the like
        raise NumericalError(str(exc)) from exc
    for i in range(remaining.size()):
        g = remaining.at(i)
        if g is None or not len(g.keys()):
            continue
        out.append((frozenset(g.keys()), gtsam.LinearContainerFactor(g, subset_values(values, list(g.keys())))))
    return out
