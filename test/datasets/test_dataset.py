"""Dataset generation as a user runs it: real solves, real processes killed and resumed, real files."""

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from hjrno_ros.datasets import dataset

CI = dataset.load_config("ci")


def hjrno(*args):
    return subprocess.run([sys.executable, "-m", "hjrno_ros.cli", *args], capture_output=True, text=True)


def write_config(path: Path, **changes) -> Path:
    raw = yaml.safe_load((dataset.config_dir() / "ci.yaml").read_text())
    raw.update(changes)
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.fixture(scope="module")
def ci_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("ci")
    out = hjrno("generate", "--experiment", "ci", "--out", str(root), "--quiet")
    assert out.returncode == 0, out.stderr
    return root


def test_generate_writes_complete_validated_splits(ci_run):
    train, test = dataset.load_split(ci_run / "train.h5"), dataset.load_split(ci_run / "test.h5")
    assert train.target.shape == (CI.n_train, *CI.grid) and test.value.shape == (CI.n_test, *CI.grid)
    assert train.converged.all() and test.converged.all()
    assert np.all(train.value <= train.target + 1e-5)
    seeds = [s.seed for s in train.scenarios + test.scenarios]
    assert len(set(seeds)) == len(seeds)
    # Each stored sample is the scenario its seed describes.
    np.testing.assert_array_equal(train.target[2], train.scenarios[2].target(train.grid))
    assert not list(ci_run.rglob("*.tmp"))


def test_generation_is_reproducible(ci_run):
    _, target, value, report = dataset.solve_sample(CI, "train", 1)
    stored = dataset.load_split(ci_run / "train.h5")
    np.testing.assert_array_equal(stored.target[1], target)
    np.testing.assert_allclose(stored.value[1], value, atol=1e-6)


def test_killed_run_resumes_without_duplicates_or_losses(tmp_path):
    config = write_config(tmp_path / "long.yaml", name="long", n_train=10, n_test=2)
    root = tmp_path / "long"
    args = [sys.executable, "-m", "hjrno_ros.cli", "generate", "--experiment", "long", "--config", str(config),
            "--out", str(root), "--quiet"]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 120
    while len(list((root / "samples" / "train").glob("[0-9]*.h5"))) < 2 and time.time() < deadline:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = len(list((root / "samples" / "train").glob("[0-9]*.h5")))
    assert 2 <= done_before < 10, "the kill should land mid-run"
    assert not (root / "train.h5").exists()
    out = subprocess.run(args, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert f"solved {12 - done_before} sample(s)" in out.stdout
    train = dataset.load_split(root / "train.h5")
    assert len(train.scenarios) == 10 and [s.seed for s in train.scenarios] == list(range(10))
    assert not list(root.rglob("*.tmp"))


def test_seed_override_gives_new_scenarios(ci_run, tmp_path):
    out = hjrno("generate", "--experiment", "ci", "--seed", "7", "--n-train", "1", "--n-test", "1", "--out",
                str(tmp_path / "more"), "--quiet")
    assert out.returncode == 0, out.stderr
    train, test = (dataset.load_split(tmp_path / "more" / f"{s}.h5") for s in ("train", "test"))
    assert [s.seed for s in train.scenarios] == [7] and [s.seed for s in test.scenarios] == [7 + 1_000_000]
    assert not np.array_equal(train.target[0], dataset.load_split(ci_run / "train.h5").target[0])


def test_inflation_solves_for_grown_obstacles(ci_run, tmp_path):
    """--inflation r: the target is l − r exactly and V∞ is the plain one lowered by r (up to the solver's
    stopping time); configs without inflation keep their digest (model cards name datasets by it)."""
    out = hjrno("generate", "--experiment", "ci", "--n-train", "1", "--n-test", "0", "--inflation", "0.25",
                "--out", str(tmp_path / "inflated"), "--quiet")
    assert out.returncode == 0, out.stderr
    grown, plain = dataset.load_split(tmp_path / "inflated" / "train.h5"), dataset.load_split(ci_run / "train.h5")
    assert grown.config.inflation == 0.25 and grown.scenarios[0].seed == plain.scenarios[0].seed
    np.testing.assert_array_equal(grown.target[0], plain.target[0] - np.float32(0.25))
    shift = plain.value[0] - grown.value[0]  # V∞[l − r] = V∞[l] − r: the solve commutes with the constant
    assert np.abs(shift - 0.25).mean() < 2e-3 and np.abs(shift - 0.25).max() < 0.1, np.abs(shift - 0.25).max()
    assert dataset.ExperimentConfig(**{**CI.as_dict(), "inflation": 0.0}).digest() == CI.digest()
    assert "inflation" not in CI.as_dict() and grown.config.digest() != dataset.ExperimentConfig(
        **{**grown.config.as_dict(), "inflation": 0.0}).digest()


def test_shards_merge_into_the_same_dataset(ci_run, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for k, folder in ((0, a), (1, b)):
        out = hjrno("generate", "--experiment", "ci", "--out", str(folder), "--shard", f"{k}/2", "--quiet")
        assert out.returncode == 0 and "other shards pending" in out.stdout, out.stderr
    out = hjrno("merge", "--out", str(a), str(b))
    assert out.returncode == 0, out.stderr
    merged, single = dataset.load_split(a / "train.h5"), dataset.load_split(ci_run / "train.h5")
    np.testing.assert_array_equal(merged.target, single.target)
    np.testing.assert_allclose(merged.value, single.value, atol=1e-6)


def test_corrupt_sample_is_redone_and_changed_config_refused(ci_run, tmp_path):
    root = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(ci_run), str(root)], check=True)
    (root / "samples" / "train" / "000001.h5").write_bytes(b"garbage")
    out = hjrno("generate", "--experiment", "ci", "--out", str(root), "--quiet")
    assert out.returncode == 0 and "solved 1 sample(s)" in out.stdout, out.stdout + out.stderr
    other = write_config(tmp_path / "other.yaml", n_train=5)
    out = hjrno("generate", "--experiment", "ci", "--config", str(other), "--out", str(root), "--quiet")
    assert out.returncode == 2 and "different config" in out.stderr


@pytest.mark.parametrize("changes, message", [
    ({"n_train": -3}, "non-negative"),
    ({"grid": [20, 20, 5]}, "4 axes"),
    ({"family": "moon"}, "unknown family"),
    ({"options": {"radius": -1.0}}, "radius"),
    ({"options": {"colour": "red"}}, "unknown option"),
    ({"solver": {"accuracy": "best"}}, "accuracy"),
    ({"family": "parametric", "n_train": 200}, "lattice"),
    ({"bogus": 1}, "unknown key"),
    ({"inflation": -0.1}, "inflation"),
    ({"family": "air3d", "grid": [11, 11, 11], "inflation": 0.1}, "inflation applies to car families"),
])
def test_bad_configs_fail_with_one_line_and_clobber_nothing(tmp_path, changes, message):
    root = tmp_path / "out"
    root.mkdir()
    precious = root / "train.h5"
    precious.write_bytes(b"an earlier dataset")
    config = write_config(tmp_path / "bad.yaml", **changes)
    out = hjrno("generate", "--experiment", "bad", "--config", str(config), "--out", str(root), "--quiet")
    assert out.returncode == 2, out.stdout + out.stderr
    assert message in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert precious.read_bytes() == b"an earlier dataset"
    assert sorted(p.name for p in root.iterdir()) == ["train.h5"]


def test_unknown_experiment_lists_the_known_ones():
    out = hjrno("generate", "--experiment", "nope")
    assert out.returncode == 2 and "known experiments" in out.stderr and "single" in out.stderr


def test_show_draws_samples(ci_run, tmp_path):
    out = hjrno("show", "--dataset", str(ci_run / "train.h5"), "--out", str(tmp_path / "s.png"), "--samples", "2")
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "s.png").read_bytes()[:4] == b"\x89PNG"
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"nope")
    out = hjrno("show", "--dataset", str(bad))
    assert out.returncode == 2 and "unreadable" in out.stderr


def _stat(pid: int) -> list[str]:
    """Fields of /proc/PID/stat after the command name (state, ppid, ...); [] once the process is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return []


def _running(pid: int) -> bool:
    return _stat(pid)[:1] not in ([], ["Z"])  # a zombie has ended; only its parent's reaping is left


def test_workers_end_when_the_generating_process_is_killed(tmp_path):
    """``kill -9`` of ``hjrno generate --workers 2`` alone (not its group) leaves no worker solving on."""
    config = write_config(tmp_path / "long.yaml", name="long", n_train=40, n_test=2)
    args = [sys.executable, "-m", "hjrno_ros.cli", "generate", "--experiment", "long", "--config", str(config),
            "--workers", "2", "--out", str(tmp_path / "long"), "--quiet"]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 120
        while not list((tmp_path / "long" / "samples" / "train").glob("[0-9]*.h5")) and time.time() < deadline:
            time.sleep(0.05)
        workers = [int(p.parent.name) for p in Path("/proc").glob("[0-9]*/cmdline")
                   if _stat(int(p.parent.name))[1:2] == [str(proc.pid)] and b"spawn_main" in p.read_bytes()]
        assert len(workers) == 2, "two solving workers should be running"
        proc.kill()
        proc.wait()
        deadline = time.time() + 20
        while any(map(_running, workers)) and time.time() < deadline:
            time.sleep(0.1)
        assert not [w for w in workers if _running(w)], "workers outlived the killed generator"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # whatever is left of the group
