"""The same params and seeds give byte-identical outputs, on any processor (issue 27)."""

from __future__ import annotations

import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numpy._core._multiarray_umath import __cpu_dispatch__

from pipeline.geometry import strict_math
from tests.project import environment, run_pipeline, tiny_params_tree, write_params

# Every SIMD extension NumPy dispatches to at run time (X86_V3, X86_V4, AVX512_ICL, ... on x86-64
# with NumPy 2.4), so its kernels run the baseline paths, and glibc's libm without its FMA and
# AVX2 variants: what a processor without them computes.
LESSER_PROCESSOR = {"NPY_DISABLE_CPU_FEATURES": " ".join(__cpu_dispatch__),
                    "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA"}


def run_all(folder: Path, params: Path) -> dict[str, bytes]:
    for arguments in (("routes", "--out", "routes"), ("simulate", "--routes", "routes", "--out", "simulated"),
                      ("data-report", "--routes", "routes", "--simulated", "simulated", "--out", "reports")):
        result = run_pipeline(arguments[0], "--params", str(params), *arguments[1:], cwd=folder)
        assert result.returncode == 0, result.stderr
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*"))
            if path.is_file() and path != params}


def test_same_params_give_identical_files(tmp_path: Path) -> None:
    """Two runs in different folders write the same bytes: Parquet, JSON and PNG."""
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    tree = tiny_params_tree()
    files_first = run_all(first, write_params(tree, first / "params.yaml"))
    files_second = run_all(second, write_params(tree, second / "params.yaml"))
    assert sorted(files_first) == sorted(files_second)
    assert any(name.endswith("plots.parquet") for name in files_first)
    for name, content in files_first.items():
        assert content == files_second[name], f"{name} differs between two identical runs"


def test_simulation_seed_changes_plots_not_routes(tmp_path: Path) -> None:
    """The radar's seed is independent of the routes' seeds."""
    tree = tiny_params_tree()
    first = run_all(tmp_path, write_params(tree, tmp_path / "params.yaml"))
    tree["simulate"]["seed"] += 1
    second = run_all(tmp_path, write_params(tree, tmp_path / "params.yaml"))
    assert first["routes/train.parquet"] == second["routes/train.parquet"]
    assert first["simulated/train/plots.parquet"] != second["simulated/train/plots.parquet"]


def data_stage_files(folder: Path, params: Path, extra_environment: dict[str, str]) -> dict[str, bytes]:
    """The files of the routes, simulate and scenes stages run in `folder` with `extra_environment`."""
    for arguments in (("routes", "--out", "routes"), ("simulate", "--routes", "routes", "--out", "simulated"),
                      ("scenes", "--out", "scenes")):
        result = subprocess.run([sys.executable, "-m", "pipeline", arguments[0], "--params", str(params),
                                 *arguments[1:]], cwd=folder, env={**environment(), **extra_environment},
                                capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
    return {str(path.relative_to(folder)): path.read_bytes() for path in sorted(folder.rglob("*.parquet"))}


def test_data_stages_write_the_same_bytes_without_the_processors_simd_and_fma(tmp_path: Path) -> None:
    """The data stages' files do not depend on which vector kernels NumPy and the C library pick
    (NumPy's AVX-512 arctan2, arcsin, exp, log10, power and glibc's FMA sin and cos differ from
    the others in the last bit, which changed the files' bytes before strict_math)."""
    tree = tiny_params_tree(routes_per_strategy=1)
    files = {}
    for name, extra in (("this", {}), ("lesser", LESSER_PROCESSOR)):
        (tmp_path / name).mkdir()
        files[name] = data_stage_files(tmp_path / name, write_params(tree, tmp_path / name / "params.yaml"), extra)
    assert sorted(files["this"]) == sorted(files["lesser"])
    assert {"routes/train.parquet", "simulated/train/truth.parquet", "scenes/plots.parquet"} <= set(files["this"])
    for name, content in files["this"].items():
        assert content == files["lesser"][name], f"{name} differs without the processor's SIMD and FMA"


LONG_DOUBLE = np.finfo(np.longdouble).nmant >= 63  # x87 extended precision: a reference 11 bits finer


@pytest.mark.skipif(not LONG_DOUBLE, reason="needs an 80-bit long double as the reference")
@pytest.mark.parametrize(("function", "reference", "low", "high", "ulps"), [
    (strict_math.sin, np.sin, -3000.0, 3000.0, 1.0),
    (strict_math.cos, np.cos, -3000.0, 3000.0, 1.0),
    (strict_math.atan, np.arctan, -40.0, 40.0, 1.0),
    (strict_math.asin, np.arcsin, -1.0, 1.0, 1.0),
    (strict_math.exp, np.exp, -700.0, 700.0, 1.0),
    (strict_math.log, np.log, 1e-300, 1e300, 1.0),
    (strict_math.log10, np.log10, 1e-30, 1e30, 2.0),
])
def test_strict_math_is_within_its_ulps_of_a_long_double_reference(function, reference, low, high, ulps) -> None:
    """fdlibm's accuracy (below 1 ulp; log10, composed, below 2), arguments spread over their range
    (log-uniform for log and log10) and at fdlibm's branch points."""
    rng = np.random.default_rng(27)
    spread = (np.exp(rng.uniform(np.log(low), np.log(high), 50_000)) if low > 0.0
              else rng.uniform(low, high, 50_000))
    branches = np.array([0.0, 0.3, 0.4375, 0.5, 0.6875, 0.78125, np.pi / 4.0, 0.975, 1.0, 1.1875, 2.4375, 3.0])
    x = np.concatenate([spread, branches[(branches >= low) & (branches <= high)]])
    exact = reference(x.astype(np.longdouble))
    error = np.abs(function(x).astype(np.longdouble) - exact) / np.spacing(np.abs(exact.astype(np.float64)))
    assert float(error.max()) < ulps


def test_strict_atan2_quadrants_and_zeros() -> None:
    """atan2 in every quadrant within 2 ulp of the reference, and C99's values on the axes
    (signed zeros, +-pi, +-pi/2), exactly."""
    y, x = np.meshgrid([-3.0, -0.0, 0.0, 2.0], [-5.0, -0.0, 0.0, 7.0])
    axes = (y == 0.0) | (x == 0.0)
    assert np.array_equal(strict_math.atan2(y, x)[axes], np.arctan2(y, x)[axes])
    assert np.array_equal(np.signbit(strict_math.atan2(y, x)), np.signbit(np.arctan2(y, x)))
    rng = np.random.default_rng(1)
    y, x = rng.uniform(-20.0, 20.0, (2, 50_000))
    exact = np.arctan2(y.astype(np.longdouble), x.astype(np.longdouble))
    error = np.abs(strict_math.atan2(y, x).astype(np.longdouble) - exact) / np.spacing(np.abs(exact.astype(float)))
    assert float(error.max()) < 2.0


def test_strict_math_domain_errors() -> None:
    """Arguments where the algorithm would lose its accuracy are refused, not computed badly."""
    with pytest.raises(ValueError, match="sin/cos argument"):
        strict_math.sin(np.array([1e7]))
    with pytest.raises(ValueError, match="exp argument"):
        strict_math.exp(np.array([710.0]))
    assert np.isnan(strict_math.sin(np.array([np.nan, np.inf]))).all()
    assert np.array_equal(strict_math.log(np.array([0.0, np.inf])), [-np.inf, np.inf])
    assert np.isnan(strict_math.log(np.array([-1.0]))).all() and np.isnan(strict_math.asin(np.array([1.5]))).all()


# MKL as on a processor without AVX-512 (MKL's own cap on the instructions it uses): what the
# trainings of an AVX2 machine compute, unless the package pins MKL's code path (pipeline/__init__.py).
LESSER_MKL = {"MKL_ENABLE_INSTRUCTIONS": "AVX2"}
TRAININGS = (("train", "--kind", "filter", "--windows", "data/windows"),  # float32 GRU: MKL, oneDNN, ATen
             ("train-kalman-net", "--simulated", "data/simulated", "--windows", "data/windows"))  # float64, Adam


def trained_files(tiny: Path, folder: Path, extra_environment: dict[str, str]) -> dict[str, bytes]:
    """The model files the tiny pipeline's filter and network-scaled filter trainings write into `folder`."""
    (folder / "models").mkdir(parents=True)
    (folder / "models" / "kalman_tuned.json").write_bytes((tiny / "models" / "kalman_tuned.json").read_bytes())
    for arguments in TRAININGS:
        result = subprocess.run(
            [sys.executable, "-m", "pipeline", "-q", *arguments, "--params", "params.yaml",
             "--models", str(folder / "models"), "--reports", str(folder / "reports")], cwd=tiny,
            env={**environment(), **extra_environment, "MLFLOW_TRACKING_URI": f"sqlite:///{folder / 'mlflow.db'}"},
            capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
    return {path.name: path.read_bytes() for path in sorted((folder / "models").iterdir())}


def test_trainings_write_the_same_bytes_with_mkls_avx2_kernels(tiny_pipeline: Path, tmp_path: Path) -> None:
    """A training gives the same model on an AVX2 processor as on an AVX-512 one: MKL capped at AVX2
    changed every model's bytes before the package pinned the kernels (all six tiny trainings). On a
    processor without AVX-512 the two runs are alike anyway."""
    this = trained_files(tiny_pipeline, tmp_path / "this", {})
    lesser = trained_files(tiny_pipeline, tmp_path / "lesser", LESSER_MKL)
    assert {"filter.pt", "kalman_net.pt", "kalman_gradient.json"} <= set(this)
    for name, content in this.items():
        assert content == lesser[name], f"{name} differs with MKL's AVX2 kernels"


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="kernels are pinned on x86-64 only")
def test_importing_the_package_pins_the_kernels_and_keeps_the_users_choice() -> None:
    script = "import os, pipeline; print(os.environ['ATEN_CPU_CAPABILITY'], os.environ['MKL_CBWR'])"
    pinned = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            env={k: v for k, v in environment().items() if k not in ("ATEN_CPU_CAPABILITY", "MKL_CBWR")})
    chosen = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            env={**environment(), "ATEN_CPU_CAPABILITY": "avx512"})
    assert pinned.stdout.split() == ["avx2", "AVX2,STRICT"]
    assert chosen.stdout.split()[0] == "avx512"
