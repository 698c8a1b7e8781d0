"""What ``pointviz render`` does around its work: it imports only what the render needs, builds
only its own command's parser, estimates the radii beside the camera fit, and, run as a program,
ends as soon as its output is written, with nothing lost."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pointviz.errors import FileFormatError, InputError

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"

#: Modules the render command has no use for: heavy imports a run must not pay for.
NOT_FOR_RENDER = ("open3d", "scipy", "matplotlib", "dask", "distributed", "laspy", "trimesh",
                  "pyvista", "pointviz.path", "pointviz.viewer", "pointviz.comparison",
                  "pointviz.commands.path", "pointviz.commands.view", "pointviz.commands.compare",
                  # the denoiser's library is called through ctypes: not pyoidn's cffi wrapper;
                  # scene keys (OpenSSL's hashes) are not computed
                  "pyoidn", "cffi", "hashlib")


@pytest.fixture(scope="module")
def raw_scans(tmp_path_factory):
    """A .conf of small registered raw scans of a sphere (ASCII PLY): the fit's path."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        import bench_pipeline as bp
    finally:
        sys.path.remove(str(BENCHMARKS))
    folder = tmp_path_factory.mktemp("scans")
    return bp.write_conf(folder, bp.sphere_scans(seed=4, grid=40), "ascii")


def _run(code: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def test_render_imports_only_what_it_needs(raw_scans, tmp_path):
    out = tmp_path / "a.png"
    code = ("import json, sys\n"
            "from pointviz.cli import main\n"
            "status = main(sys.argv[1:])\n"
            "print(json.dumps([status, sorted(sys.modules)]))\n")
    proc = _run(code, "render", raw_scans, "-o", out, "--width", "48", "--height", "32",
                "--spp", "1")
    assert proc.returncode == 0, proc.stderr
    status, modules = json.loads(proc.stdout.strip().splitlines()[-1])
    assert status == 0 and out.exists()
    assert "surface fit" in proc.stderr  # raw scans: the fit ran
    loaded = [m for m in NOT_FOR_RENDER if m in modules]
    assert not loaded, f"render imported {loaded}"


def test_a_named_command_gets_the_same_parser_as_the_full_one(tmp_path):
    from pointviz.cli import COMMANDS, build_parser

    argv = ["render", "cloud.ply", "-o", str(tmp_path / "x.png"), "--width", "80", "--lod",
            "auto", "--no-denoise", "--light", "1,2,3"]
    full, own = build_parser().parse_args(argv), build_parser(argv).parse_args(argv)
    assert {k: v for k, v in vars(full).items() if k != "run"} == \
        {k: v for k, v in vars(own).items() if k != "run"}
    assert own.exit_fast is True
    # the render command's parser alone has only its own subcommand; without a command (help,
    # version, a typo) the parser has them all
    names = build_parser(argv)._subparsers._group_actions[0].choices
    assert list(names) == ["render"]
    for other in ([], ["--help"], ["rendr", "x"]):
        assert list(build_parser(other)._subparsers._group_actions[0].choices) == list(COMMANDS)


def test_render_run_as_a_program_ends_with_its_output_written(raw_scans, tmp_path):
    """Run as a program, the command ends the process without the interpreter's teardown:
    the PNG is complete and renamed into place, its line on standard output is flushed (to a
    pipe here), and the folder holds nothing else."""
    out = tmp_path / "b.png"
    proc = subprocess.run([sys.executable, "-m", "pointviz.cli", "render", str(raw_scans), "-o",
                           str(out), "--width", "40", "--height", "30", "--spp", "1"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"{out}: 40x30")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.png"]
    with Image.open(out) as img:
        img.load()
        assert img.size == (40, 30)
    # an error still exits through the interpreter, with its one-line message and status 2
    proc = subprocess.run([sys.executable, "-m", "pointviz.cli", "render", str(raw_scans), "-o",
                           str(out), "--width", "40"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "exists" in proc.stderr


def test_load_can_leave_the_radii_to_the_caller(tmp_path, rng):
    from pointviz.io import estimate_radii_of, load

    p = rng.normal(size=(3000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    path = tmp_path / "ball.xyz"
    np.savetxt(path, p, fmt="%.9f")
    full = load(path)
    part = load(path, estimate="normals")
    assert not part.has_radii and part._radii is None  # not estimated yet
    np.testing.assert_array_equal(part.normals, full.normals)
    estimate_radii_of(part, path)
    np.testing.assert_array_equal(part.radii, full.radii)
    with pytest.raises(InputError, match="estimate"):
        load(path, estimate="radii")
    assert load(path, estimate=np.True_)._radii is not None


def test_radii_errors_name_the_file_when_estimated_beside_the_camera_fit(tmp_path, capsys):
    """All points at one position, with normals given: the radii cannot be estimated, and the
    command says so naming the file, whether the radii are estimated in ``load`` or beside the
    camera fit."""
    from pointviz.cli import main
    from pointviz.io import estimate_radii_of, load

    path = tmp_path / "stack.xyzn"
    np.savetxt(path, np.tile([1.0, 2.0, 3.0, 0.0, 0.0, 1.0], (50, 1)), fmt="%.3f")
    with pytest.raises(FileFormatError, match="stack.xyzn"):
        load(path)
    cloud = load(path, estimate="normals")
    with pytest.raises(FileFormatError, match="stack.xyzn"):
        estimate_radii_of(cloud, path)
    out = tmp_path / "x.png"
    assert main(["render", str(path), "-o", str(out), "--width", "16", "--no-denoise"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "stack.xyzn" in err[0] and "radii" in err[0]
    assert not out.exists()


def test_render_run_as_a_program_uses_one_blas_thread_unless_told(raw_scans, tmp_path):
    code = ("import os, sys\n"
            "import pointviz.cli as cli\n"
            "def end(status):\n"
            "    print(os.environ.get('OPENBLAS_NUM_THREADS'), 'numpy' in sys.modules)\n"
            "    sys.stdout.flush()\n"
            "    os._exit(status)\n"
            "cli._exit_now = end\n"
            "sys.argv = ['pointviz', *sys.argv[1:]]\n"
            "cli.main()\n")
    argv = ["render", raw_scans, "-o", tmp_path / "c.png", "--width", "24", "--spp", "1",
            "--no-denoise"]
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    for given, seen in ((None, "1"), ("2", "2")):
        proc = subprocess.run([sys.executable, "-c", code, *map(str, argv), "--overwrite"],
                              capture_output=True, text=True, timeout=300,
                              env=env if given is None else {**env, "OPENBLAS_NUM_THREADS": given})
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.splitlines()[-1].split() == [seen, "True"]


def test_render_run_as_a_program_keeps_the_memory_it_frees(raw_scans, tmp_path):
    """Run as a program, render sets glibc's allocator to reuse freed memory (mallopt accepts
    both settings here, on Linux); called as a function, main() leaves the process alone."""
    code = ("import os, sys\n"
            "import pointviz.cli as cli\n"
            "calls = []\n"
            "set_it = cli._reuse_freed_memory\n"
            "cli._reuse_freed_memory = lambda: calls.append(set_it()) or calls[-1]\n"
            "def end(status):\n"
            "    print(calls)\n"
            "    sys.stdout.flush()\n"
            "    os._exit(status)\n"
            "cli._exit_now = end\n"
            "sys.argv = ['pointviz', *sys.argv[1:]]\n"
            "if sys.argv[1] == 'render':\n"
            "    cli.main()\n"
            "else:\n"
            "    cli.main(['render', *sys.argv[2:]])\n"
            "    end(0)\n")
    for command, seen in (("render", [sys.platform.startswith("linux")]), ("as-function", [])):
        argv = [command, raw_scans, "-o", tmp_path / f"{command}.png", "--width", "24",
                "--spp", "1", "--no-denoise"]
        proc = subprocess.run([sys.executable, "-c", code, *map(str, argv)],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.splitlines()[-1] == str(seen)
