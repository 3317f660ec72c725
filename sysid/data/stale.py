"""Which groups of a campaign were computed from given manoeuvres (and go stale with them).

:func:`stale_groups` answers it for ``sysid import --replace``
(:func:`sysid.data.netcdf.add_maneuvers`): the groups to remove when manoeuvres are
replaced, each with the reason. The rules follow how each group records its inputs
(``docs/data_model.md``):

* ``/frequency_response*`` and ``/cross_control_coherence``: stale when their ``records``
  attribute names a replaced manoeuvre, or when they do not record their records (the cross-
  control summary never does: it uses every sweep);
* ``/models/<method>``: stale when its ``records`` attribute (time-domain fits) names a
  replaced manoeuvre; a model without ``records`` (frequency-domain fits) when a frequency
  response is stale;
* ``/verification/<maneuver>``: when that manoeuvre is replaced or any model is stale (it
  holds every model's simulation); ``/comparison``, ``/validation``: when any model is
  stale; ``/handling_qualities``: when a model or a frequency response is;
  ``/transfer_functions/<pair>/<source>``: a ``data`` source when a frequency response is,
  a model source when that model is; ``/hold_margins``: only when its ``model`` is a
  stale model (it is computed from the truth linearisation otherwise);
* the truth's groups (``/trim``, ``/linearization``, ``/linearization_full``,
  ``/closed_loop``) and other manoeuvres never depend on flight data;
* any other group (a kind this rule set does not know) is stale: it cannot be shown
  not to depend on the data.

Parents left without their stale children lose their stage stamps (``workflow_key``,
``workflow_elapsed_s``), and so does ``/maneuvers``: those stamps said which inputs produced
the group, which is no longer true.
"""

from __future__ import annotations

import xarray as xr

__all__ = ["TRUTH_GROUPS", "STAMP_ATTRS", "stale_groups"]

#: Groups computed from the truth model alone, never from flight data.
TRUTH_GROUPS = ("/trim", "/linearization", "/linearization_full", "/closed_loop")
#: Stage stamps that say which inputs produced a group (sysid.pipeline.study).
STAMP_ATTRS = ("workflow_key", "workflow_elapsed_s")

_KNOWN_PARENTS = ("/maneuvers", "/models", "/verification", "/validation",
                  "/transfer_functions")


def _records(attrs) -> list[str] | None:
    value = attrs.get("records")
    if value is None:
        return None
    if isinstance(value, str):
        return [r.strip() for r in value.split(",") if r.strip()]
    return [str(r) for r in value]


def _depends_on(attrs, names: set[str]) -> bool:
    records = _records(attrs)
    return records is None or bool(names & set(records))


def stale_groups(tree: xr.DataTree, names) -> dict[str, str]:
    """``{group path: reason}`` of the groups of ``tree`` computed from manoeuvres ``names``
    (directly or through other stale groups), by the rules of the module docstring.
    Leaf-most paths; a parent is listed when every child of it is. Empty when nothing in
    ``tree`` used ``names`` (e.g. a campaign holding only manoeuvres)."""
    names = set(names)
    if not names:
        return {}
    paths = {node.path: node for node in tree.subtree}
    stale: dict[str, str] = {}

    def leaves(prefix):
        return [p for p in paths if p.startswith(prefix + "/")
                and p.count("/") == prefix.count("/") + 1]

    fr_paths = [p for p in paths if p.count("/") == 1 and (
        p.startswith("/frequency_response") or p == "/cross_control_coherence")]
    for p in fr_paths:
        if _depends_on(paths[p].attrs, names):
            used = _records(paths[p].attrs)
            stale[p] = ("records " + ", ".join(sorted(names & set(used))) if used is not None
                        else "does not record its records")
    fr_stale = any(p.startswith("/frequency_response") for p in stale)
    for p in leaves("/models"):
        attrs = paths[p].attrs
        records = _records(attrs)
        if records is not None:
            if names & set(records):
                stale[p] = "fitted to " + ", ".join(sorted(names & set(records)))
        elif fr_stale:
            stale[p] = "fitted to a stale frequency response"
    stale_models = {p.rsplit("/", 1)[1] for p in stale if p.startswith("/models/")}
    for p in leaves("/verification"):
        maneuver = p.rsplit("/", 1)[1]
        if maneuver in names:
            stale[p] = "verification on a replaced manoeuvre"
        elif stale_models:
            stale[p] = "simulates stale model(s) " + ", ".join(sorted(stale_models))
    if stale_models:
        for p in ["/comparison", *leaves("/validation")]:
            if p in paths:
                stale[p] = "built from stale model(s) " + ", ".join(sorted(stale_models))
    if "/handling_qualities" in paths and (stale_models or fr_stale):
        stale["/handling_qualities"] = "built from stale responses or models"
    if "/hold_margins" in paths and str(paths["/hold_margins"].attrs.get("model", "")) in \
            stale_models:
        stale["/hold_margins"] = "built from a stale model"
    for pair in leaves("/transfer_functions"):
        for p in leaves(pair):
            source = str(paths[p].attrs.get("source", p.rsplit("/", 1)[1]))
            if (source == "data" and fr_stale) or source in stale_models:
                stale[p] = f"fitted to stale {source}"
    known = set(TRUTH_GROUPS) | {"/", "/comparison", "/handling_qualities", "/hold_margins"}
    known |= set(fr_paths)
    for p in paths:
        top = "/" + p.strip("/").split("/")[0] if p != "/" else "/"
        if p in known or top in _KNOWN_PARENTS or top in known:
            continue
        if not any(p.startswith(s + "/") for s in stale):
            stale[p] = "unknown group: cannot tell whether it used the manoeuvres"
    # Report a parent whose every child is stale as the parent itself.
    for parent in ("/verification", "/validation", "/models", "/transfer_functions"):
        children = leaves(parent)
        if parent in paths and children and all(
                c in stale or (leaves(c) and all(g in stale for g in leaves(c)))
                for c in children):
            reasons = sorted({stale.pop(g) for c in children for g in [c, *leaves(c)]
                              if g in stale})
            stale[parent] = "; ".join(reasons)
    # Only the top-most unknown paths.
    return {p: r for p, r in stale.items()
            if not any(p.startswith(q + "/") for q in stale if q != p)}
