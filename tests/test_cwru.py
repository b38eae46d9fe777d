"""The CWRU importer: real records (skipped where absent), synthetic records, bad files."""

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from bayesdoor.bearing import import_cwru, read_cwru, read_record, settle_sampling_rate
from bayesdoor.io import load_campaign, validate_campaign

DATA = Path(__file__).parents[1] / ".." / "shared" / "data" / "cwru"
G = 9.80665


@pytest.fixture(scope="module")
def campaign():
    if not (DATA / "Normal" / "Normal_0.mat").is_file():
        pytest.skip(f"the CWRU records are not at {DATA.resolve()}")
    return read_cwru(DATA)


def test_real_records_become_runs(campaign):
    assert campaign.attrs["system"] == "bearing"
    assert campaign.attrs["sampling_rate_hz"] == 12000.0
    assert list(campaign.channel.values) == ["DE"]
    assert campaign.sizes["time"] == 12000
    states = campaign.state.values
    counts = {s: int((states == s).sum()) for s in np.unique(states)}
    assert counts == {"healthy": 20, "inner_race": 60, "outer_race": 60, "ball": 60}
    records = campaign.record.values
    assert len(np.unique(records)) == 19
    faults = states != "healthy"
    assert set(campaign.split.values[faults]) == {"test"}
    np.testing.assert_array_equal(campaign.fault_size_in.values[~faults], 0.0)
    assert set(np.round(campaign.fault_size_in.values[faults], 3)) == {0.007, 0.014, 0.021}
    assert set(campaign.load_hp.values) == {0.0, 1.0}
    ir = campaign.sel(run=records == "IR021_1")
    assert set(ir.state.values) == {"inner_race"} and set(ir.load_hp.values) == {1.0}
    assert set(ir.fault_size_in.values) == {0.021}
    assert validate_campaign(campaign) == []


def test_healthy_runs_split_in_contiguous_blocks(campaign):
    healthy = campaign.sel(run=campaign.state.values == "healthy")
    split = list(healthy.split.values)
    assert split == ["calibration"] * 10 + ["test"] * 10
    np.testing.assert_array_equal(healthy.segment_start_s.values, np.arange(20.0))


def test_samples_are_the_file_in_m_per_s2_and_the_rpm_is_the_file(campaign):
    raw = scipy.io.loadmat(DATA / "12k_DE" / "OR007@6_0.mat")
    x = raw["X130_DE_time"].ravel()
    runs = campaign.sel(run=campaign.record.values == "OR007@6_0")
    np.testing.assert_allclose(runs.acceleration.values[1, 0], x[12000:24000] * G)
    assert set(runs.shaft_speed.values) == {float(raw["X130RPM"].ravel()[0])}


def test_the_healthy_record_is_settled_at_12_khz(campaign):
    source = json.loads(campaign.attrs["source"])
    normal = next(r for r in source["records"] if r["record"] == "Normal_0")
    assert normal["sampling_rate_hz"] == 12000.0
    assert normal["sampling_rate_margin"] > 5
    np.testing.assert_allclose(normal["sampling_rate_lines_hz"], [29.96, 60.02, 89.97], atol=0.1)
    assert source["records_settled_at_hz"] == [12000.0]


def test_import_writes_the_campaign_and_a_summary(campaign, tmp_path):
    out = tmp_path / "cwru.nc"
    summary = import_cwru(DATA, out)
    json.dumps(summary)
    assert summary["runs_per_state"]["healthy"] == 20 and summary["runs"] == 200
    assert summary["sampling_rate_hz"] == 12000.0
    assert len(summary["records"]) == 19
    back = load_campaign(out)
    assert back.sizes["run"] == 200
    with pytest.raises(FileExistsError, match="overwrite"):
        import_cwru(DATA, out)


def _write(path: Path, **arrays) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(path, arrays)
    return path


def _shaft_record(fs: float, seconds: float, rpm: float = 1797.0) -> np.ndarray:
    t = np.arange(round(fs * seconds)) / fs
    fr = rpm / 60
    rng = np.random.default_rng(0)
    lines = sum(0.01 * np.sin(2 * np.pi * h * fr * t + h) for h in (1, 2, 3))
    return (lines + 0.002 * rng.standard_normal(t.size))[:, None]


def test_synthetic_records_settle_their_rate_and_are_decimated(tmp_path):
    folder = tmp_path / "cwru"
    _write(
        folder / "Normal" / "Normal_0.mat",
        X097_DE_time=_shaft_record(48000.0, 4.0),
    )
    _write(
        folder / "12k_DE" / "IR007_1.mat",
        X105_DE_time=_shaft_record(12000.0, 3.5, 1772.0),
        X105RPM=np.array([[1772]]),
    )
    ds = read_cwru(folder, segment_s=0.5, calibration_fraction=0.25)
    source = json.loads(ds.attrs["source"])
    rates = {r["record"]: r["sampling_rate_hz"] for r in source["records"]}
    assert rates == {"Normal_0": 48000.0, "IR007_1": 12000.0}
    # no X097RPM: the stand's nominal speed at 0 hp
    normal = source["records"][0]
    assert (normal["shaft_speed_rpm"], normal["rpm_source"]) == (1797.0, "nominal")
    assert ds.sizes["time"] == 6000
    # 4 s at 48 kHz brought to 12 kHz: eight segments, the first two calibration
    healthy = ds.sel(run=ds.state.values == "healthy")
    assert list(healthy.split.values) == ["calibration"] * 2 + ["test"] * 6
    assert (ds.state.values == "inner_race").sum() == 7


def test_settle_refuses_an_undecided_record():
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="cannot settle the sampling rate"):
        settle_sampling_rate(rng.standard_normal(48000), 1797.0)


def test_a_folder_that_contradicts_the_spectrum_is_refused(tmp_path):
    path = _write(
        tmp_path / "12k_DE" / "B007_0.mat",
        X118_DE_time=_shaft_record(48000.0, 2.0),
        X118RPM=np.array([[1797]]),
    )
    with pytest.raises(ValueError, match=r"B007_0\.mat: its folder says 12000 Hz"):
        read_cwru(path.parent.parent)


@pytest.mark.parametrize(
    ("name", "arrays", "message"),
    [
        (
            "IR007_0.mat",
            {"X105_FE_time": np.zeros((10, 1)), "X105RPM": np.array([[1797]])},
            r"IR007_0\.mat: no X<nnn>_DE_time key \(keys: X105RPM, X105_FE_time\)",
        ),
        (
            "Normal_1.mat",
            {
                "X098_DE_time": np.zeros((10, 1)),
                "X099_DE_time": np.zeros((10, 1)),
                "X099RPM": np.array([[1772]]),
            },
            r"Normal_1\.mat: holds the keys of 2 records \(X098, X099\)",
        ),
        (
            "X097.mat",
            {"X097_DE_time": np.zeros((10, 1))},
            r"X097\.mat: cannot read the condition from the file name",
        ),
        (
            "OR007@3_0.mat",
            {"X144_DE_time": np.zeros((10, 1))},
            r"OR007@3_0\.mat: an outer-race defect at 3 o'clock",
        ),
        (
            "B007_0.mat",
            {"X118_DE_time": np.full((10, 1), np.nan)},
            r"B007_0\.mat: X118_DE_time is empty or holds values that are not finite",
        ),
    ],
)
def test_bad_files_are_named_with_what_is_wrong(tmp_path, name, arrays, message):
    path = _write(tmp_path / name, **arrays)
    with pytest.raises(ValueError, match=message):
        read_record(path)
    with pytest.raises(ValueError, match=message):
        read_cwru(tmp_path)


def test_files_of_another_layout_are_refused(tmp_path):
    text = tmp_path / "IR007_0.mat"
    text.write_text("time,acceleration\n0,1\n")
    with pytest.raises(ValueError, match=r"IR007_0\.mat: not a MATLAB \.mat file"):
        read_record(text)
    with pytest.raises(ValueError, match=r"IR007_0\.csv: not a \.mat file"):
        read_record(tmp_path / "IR007_0.csv")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match=r"holds no \.mat files"):
        read_cwru(empty)
    with pytest.raises(FileNotFoundError):
        read_cwru(tmp_path / "missing")
