"""Semantic class labels (UsdSemantics.LabelsAPI, taxonomy ``class``) and the object table.

An *object* (one instance id) is a labelled prim that has geometry below it; geometry with
no labelled ancestor is an object of its own with the empty label (class 0, unlabelled).
Ids are assigned in prim-path order, so the same stage always gives the same ids.
"""

from __future__ import annotations

from dataclasses import dataclass

from pxr import Usd, UsdGeom, UsdSemantics

TAXONOMY = "class"


def class_labels(prim: Usd.Prim, time: Usd.TimeCode = Usd.TimeCode.Default()) -> list[str]:
    """The prim's own ``class`` labels (not inherited); empty when it has none."""
    if TAXONOMY not in UsdSemantics.LabelsAPI.GetDirectTaxonomies(prim):
        return []
    value = UsdSemantics.LabelsAPI(prim, TAXONOMY).GetLabelsAttr().Get(time)
    return [str(v) for v in value] if value else []


def class_label(prim: Usd.Prim) -> str:
    """The prim's first own ``class`` label, or '' when unlabelled."""
    labels = class_labels(prim)
    return labels[0] if labels else ""


def set_class_label(prim: Usd.Prim, *labels: str) -> None:
    """Apply LabelsAPI:class to ``prim`` with ``labels``."""
    UsdSemantics.LabelsAPI.Apply(prim, TAXONOMY).CreateLabelsAttr().Set(list(labels))


def labelled_ancestor(prim: Usd.Prim) -> Usd.Prim | None:
    """The nearest prim at or above ``prim`` that carries a class label."""
    p = prim
    while p and not p.IsPseudoRoot():
        if class_labels(p):
            return p
        p = p.GetParent()
    return None


@dataclass(frozen=True)
class ObjectEntry:
    """One instance: id, the prim that carries its identity, its class label and class id."""

    instance_id: int
    prim_path: str
    label: str
    class_id: int
    mesh_paths: tuple[str, ...]


def renderable_gprims(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every active, non-guide Gprim (meshes and implicit shapes) that a renderer draws."""
    out = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Gprim):
            continue
        purpose = UsdGeom.Imageable(prim).ComputePurpose()
        if purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            continue
        out.append(prim)
    return out


def object_table(stage: Usd.Stage) -> tuple[list[ObjectEntry], list[str]]:
    """(objects, classes): the instance table and the class names, class id = index (0 = '')."""
    owners: dict[str, list[str]] = {}
    labels: dict[str, str] = {}
    for g in renderable_gprims(stage):
        owner = labelled_ancestor(g) or g
        key = str(owner.GetPath())
        owners.setdefault(key, []).append(str(g.GetPath()))
        labels[key] = class_label(owner)
    classes = [""] + sorted({lab for lab in labels.values() if lab})
    objects = [
        ObjectEntry(i + 1, path, labels[path], classes.index(labels[path]), tuple(sorted(owners[path])))
        for i, path in enumerate(sorted(owners))
    ]
    return objects, classes
