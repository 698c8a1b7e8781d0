"""The public API stays callable whatever submodules have been imported: a submodule named
like a public function would replace it on the package (``import pointviz.x`` sets
``pointviz.x`` to the module)."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pointviz


def test_public_names_survive_importing_every_submodule():
    for info in pkgutil.walk_packages(pointviz.__path__, "pointviz."):
        if info.name.startswith("pointviz.viewer"):
            continue  # GUI toolkits: imported by their own tests under a display
        importlib.import_module(info.name)
    for name in ("load", "render", "render_path", "compare", "view"):
        assert callable(getattr(pointviz, name)), name
    for name in ("PointCloud", "SurfelScene", "Scene", "Camera", "CameraPath", "Frame"):
        assert isinstance(getattr(pointviz, name), type), name


def test_import_is_cheap():
    code = ("import sys, pointviz; heavy = {'open3d', 'pyvista', 'vtk', 'dask', 'matplotlib', "
            "'embreex', 'laspy'} & set(sys.modules); print(sorted(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_one_version_source():
    """pyproject reads the version from pointviz.__version__: the installed metadata agrees."""
    from importlib.metadata import version

    assert version("pointviz") == pointviz.__version__
