"""Find scenes and targets by name: the shipped scene files, scene paths, shipped target shapes."""

from __future__ import annotations

from pathlib import Path

from ..errors import SceneError, check_input_file
from ..mesh import TriMesh
from ..targets import suggest, target
from .scene_schema import SCENE_EXTENSIONS

__all__ = ["scene_dirs", "list_scenes", "resolve_scene", "resolve_targets"]


def scene_dirs() -> list[Path]:
    """Directories searched for scenes by name: the repository's ``scenes/`` and ``warp_shape/scenes``."""
    package = Path(__file__).resolve().parents[1]
    return [d for d in (package.parent / "scenes", package / "scenes") if d.is_dir()]


def list_scenes() -> list[str]:
    """Names of the shipped scenes (loadable with ``load_scene(name)``)."""
    names = set()
    for d in scene_dirs():
        for p in d.iterdir():
            if p.suffix.lower() in SCENE_EXTENSIONS and not p.name.startswith("."):
                names.add(p.stem)
    return sorted(names)


def _scene_file(p: Path) -> Path:
    """``p``, a file, if its name is a USD scene's; a mesh or other file is named as such."""
    if p.suffix.lower() not in SCENE_EXTENSIONS:
        raise SceneError(f"{p} is not a USD scene ({', '.join(SCENE_EXTENSIONS)}); give a scene such as "
                         f"out/design.usda (a mesh file is a target: --targets {p.name})")
    return p


def resolve_scene(path_or_name) -> Path:
    """The file of a scene given as a path, or by the name of a shipped scene (``list_scenes()``)."""
    if not isinstance(path_or_name, (str, Path)) or not str(path_or_name).strip():
        raise SceneError(f"a scene is a file path or a shipped scene name ({', '.join(list_scenes())}), "
                         f"got {path_or_name!r}")
    if isinstance(path_or_name, Path) or any(s in str(path_or_name) for s in ("/", "\\")) or \
            str(path_or_name).lower().endswith(SCENE_EXTENSIONS):
        p = Path(path_or_name)
        check_input_file(p, "scene file", SceneError)
        return _scene_file(p)
    name = str(path_or_name)
    for d in scene_dirs():
        for ext in SCENE_EXTENSIONS:
            cand = d / f"{name}{ext}"
            if cand.exists():
                return cand
    p = Path(name)
    if p.is_file():
        return _scene_file(p)
    raise SceneError(f"unknown scene {name!r}{suggest(name, list_scenes())}; shipped scenes: "
                     f"{', '.join(list_scenes()) or '(none found)'} (or give a .usda file)")


def resolve_targets(targets) -> tuple[list[TriMesh], list[str]]:
    """Meshes and names for ``Scene(targets=..., target_names=...)`` from ``TriMesh`` objects or
    shipped target names (``"oval"``, resolved by ``ws.target``). A name keeps its own name
    (lower case); the i-th mesh is called ``target<i>``."""
    if isinstance(targets, (TriMesh, str)):
        targets = [targets]
    meshes, names = [], []
    for i, t in enumerate(targets):
        if isinstance(t, str):
            meshes.append(target(t))
            names.append(t.strip().lower())
        elif isinstance(t, TriMesh):
            meshes.append(t)
            names.append(f"target{i}")
        else:
            raise SceneError(f"targets[{i}] must be a TriMesh or a target name, got {type(t).__name__}")
    return meshes, names
