"""Records described by a manifest: the built-in CWRU one on the real records (skipped where
absent), a synthetic bearing of another geometry at 48 kHz, and manifests that are refused."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from typer.testing import CliRunner

from bayesdoor.bearing import (
    BearingSystem,
    ManifestError,
    envelope_spectrum,
    import_cwru,
    import_records,
    parse_manifest,
    read_manifest,
    read_records,
)
from bayesdoor.cli import app
from bayesdoor.io import load_campaign, system_of, validate_campaign

DATA = Path(__file__).parents[1] / ".." / "shared" / "data" / "cwru"
CWRU_MANIFEST = Path(__file__).parents[1] / "bayesdoor" / "bearing" / "manifests" / "cwru.toml"
G = 9.80665
runner = CliRunner()

# a deep-groove ball bearing other than CWRU's, in millimetres: 12 balls of 7.94 mm on a
# 39.04 mm pitch circle, contact angle 0; its outer-race ball-pass order from the textbook
# formula n/2 (1 - d/D) (Randall and Antoni 2011), written out here, not taken from bayesdoor
N_BALLS, BALL_MM, PITCH_MM = 12, 7.94, 39.04
BPFO_ORDER = N_BALLS / 2 * (1 - BALL_MM / PITCH_MM)  # 4.780
FS = 48000.0
SECONDS = 2.5

RIG_MANIFEST = f"""
name = "test-rig"
system = "bearing"

[files]
glob = "*.mat"
name = ['^(?P<state>N)_L(?P<load>\\d)$', '^(?P<state>O)(?P<size>\\d{{3}})_L(?P<load>\\d)$']

[states]
N = "healthy"
O = "outer_race"

[fault_size]
inch_per_unit = 0.001

[signal]
key = '^acc_g$'
unit = "g"

[sampling_rate]
hz = {FS}

[shaft_speed]
key = '^speed_rpm$'
at_load = {{ 2 = 1720.0 }}

[runs]
segment_s = 0.5
calibration_fraction = 0.4

[geometry]
n_balls = {N_BALLS}
ball_diameter_mm = {BALL_MM}
pitch_diameter_mm = {PITCH_MM}
designation = "test rig bearing"
"""

# record: (state, defect size in, load hp, rpm stored in the file or None)
RIG_RECORDS = {
    "N_L0": ("healthy", 0.0, 0, 1790.0),
    "O014_L1": ("outer_race", 0.014, 1, 1760.0),
    "O021_L2": ("outer_race", 0.021, 2, None),  # the manifest's at_load: 1720 rpm
}


def _rig_signal(state: str, rpm: float, seed: int) -> np.ndarray:
    """Acceleration in g at 48 kHz: noise and a shaft line, and for an outer-race defect a
    ring-down of a 3.5 kHz resonance at every ball pass (BPFO_ORDER x the shaft frequency)."""
    rng = np.random.default_rng(seed)
    n = round(FS * SECONDS)
    t = np.arange(n) / FS
    x = 0.02 * rng.standard_normal(n) + 0.01 * np.sin(2 * np.pi * rpm / 60 * t)
    if state == "outer_race":
        ring_t = np.arange(round(0.004 * FS)) / FS
        ring = np.exp(-2 * np.pi * 0.03 * 3500 * ring_t) * np.sin(2 * np.pi * 3500 * ring_t)
        for start in np.arange(0.0, SECONDS, 60 / (BPFO_ORDER * rpm)):
            i = round(start * FS)
            stop = min(n, i + ring.size)
            x[i:stop] += 0.5 * ring[: stop - i]
    return x


@pytest.fixture
def rig(tmp_path):
    """A folder of three synthetic .mat records and the manifest that describes them."""
    folder = tmp_path / "rig"
    folder.mkdir()
    for i, (name, (state, _, _, rpm)) in enumerate(RIG_RECORDS.items()):
        arrays = {"acc_g": _rig_signal(state, rpm or 1720.0, seed=i)[:, None]}
        if rpm is not None:
            arrays["speed_rpm"] = np.array([[rpm]])
        scipy.io.savemat(folder / f"{name}.mat", arrays)
    manifest = tmp_path / "rig.toml"
    manifest.write_text(RIG_MANIFEST)
    return folder, manifest


def test_a_bearing_of_another_geometry_at_48_khz_is_imported(rig, tmp_path):
    folder, manifest = rig
    out = tmp_path / "rig.nc"
    result = runner.invoke(app, ["import", str(manifest), str(folder), "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["importer"] == "test-rig" and summary["sampling_rate_hz"] == FS
    assert "notes" not in summary  # nothing resampled
    ds = load_campaign(out)
    assert ds.attrs["sampling_rate_hz"] == FS and ds.sizes["time"] == FS * 0.5
    # 2.5 s per record in runs of 0.5 s; the healthy record's first 40 % calibrate
    assert ds.sizes["run"] == 15
    for name, (state, size, load, rpm) in RIG_RECORDS.items():
        runs = ds.sel(run=ds.record.values == name)
        assert set(runs.state.values) == {state}
        assert set(runs.load_hp.values) == {float(load)}
        assert set(runs.shaft_speed.values) == {rpm or 1720.0}
        np.testing.assert_allclose(runs.fault_size_in.values, size)
    healthy = ds.sel(run=ds.state.values == "healthy")
    assert list(healthy.split.values) == ["calibration"] * 2 + ["test"] * 3
    stored = scipy.io.loadmat(folder / "O014_L1.mat")["acc_g"].ravel()
    runs = ds.sel(run=ds.record.values == "O014_L1")
    np.testing.assert_array_equal(runs.acceleration.values[1, 0], stored[24000:48000] * G)
    rpm_source = {r["record"]: r["rpm_source"] for r in summary["records"]}
    assert rpm_source == {"N_L0": "file", "O014_L1": "file", "O021_L2": "nominal"}
    assert validate_campaign(ds) == []

    # the campaign names its bearing: the system comes back with that geometry and rate
    settings = json.loads(ds.attrs["system_settings"])
    assert settings["sampling_rate_hz"] == FS
    assert settings["geometry"]["ball_diameter_in"] == pytest.approx(BALL_MM / 25.4)
    system = system_of(ds)
    assert isinstance(system, BearingSystem)
    assert system.sampling_rate_hz == FS and system.geometry.n_balls == N_BALLS
    assert system.geometry.orders()["bpfo"] == pytest.approx(BPFO_ORDER, rel=1e-12)


def test_the_imported_runs_show_the_bearings_own_ball_pass_frequency(rig):
    folder, manifest = rig
    ds = read_records(folder, manifest)
    system = system_of(ds)
    fault = ds.sel(run=ds.state.values == "outer_race")
    for x, rpm in zip(fault.acceleration.values[:, 0], fault.shaft_speed.values, strict=True):
        bpfo = system.fault_frequencies(rpm)["bpfo"]
        f, amplitude = envelope_spectrum(x, system.sampling_rate_hz, segment_s=0.5)
        near = (f > 50) & (f < 300)
        # the strongest envelope line: BPFO within one 2 Hz bin (CWRU's would be 25 % lower)
        assert abs(f[near][np.argmax(amplitude[near])] - bpfo) <= 2.0
    # the signature check reads the lines at this bearing's frequencies: every outer-race run
    # agrees with outer_race; read with the CWRU geometry, none does
    healthy = ds.sel(run=ds.state.values == "healthy")
    op = lambda d: np.stack([d.shaft_speed.values, d.load_hp.values], axis=-1)  # noqa: E731
    for bearing, expected in ((system, True), (BearingSystem(sampling_rate_hz=FS), False)):
        reference = bearing.signature_reference(healthy.acceleration.values, op(healthy))
        calls = bearing.signatures(reference, fault.acceleration.values, op(fault))
        assert [c["outer_race"] for c in calls] == [expected] * fault.sizes["run"]


def test_the_imported_bearing_simulates_its_own_ball_pass_frequency(rig):
    folder, manifest = rig
    system = system_of(read_records(folder, manifest))
    result = system.simulate_values(
        system.nominal(),
        [[1760.0, 1.0]],
        state="outer_race",
        severity={"impulse_amplitude": 100.0},
        duration=0.5,
    )
    assert result.signals.shape == (1, 1, 24000)
    f, amplitude = envelope_spectrum(np.asarray(result.signals[0, 0]), FS, segment_s=0.5)
    near = (f > 50) & (f < 300)
    assert abs(f[near][np.argmax(amplitude[near])] - BPFO_ORDER * 1760.0 / 60) <= 2.0


def test_records_at_another_rate_are_resampled_and_the_summary_says_so(rig, tmp_path):
    folder, manifest = rig
    text = manifest.read_text().replace(f"hz = {FS}", f"hz = {FS}\ncampaign_hz = 24000.0")
    (tmp_path / "half.toml").write_text(text)
    ds = read_records(folder, tmp_path / "half.toml")
    assert ds.attrs["sampling_rate_hz"] == 24000.0 and ds.sizes["time"] == 12000
    summary = json.loads(ds.attrs["source"])
    assert summary["notes"] == [
        "3 record(s) at 48000 Hz resampled to the campaign's 24000 Hz "
        "(scipy.signal.resample_poly): N_L0, O014_L1, O021_L2"
    ]
    assert system_of(ds).sampling_rate_hz == 24000.0


def test_csv_records_with_one_speed_and_one_load(tmp_path):
    folder = tmp_path / "csv"
    folder.mkdir()
    rng = np.random.default_rng(3)
    for name in ("healthy_a", "outer_b"):
        x = rng.standard_normal((12000, 2))
        np.savetxt(folder / f"{name}.csv", x, delimiter=",", header="time,accel", comments="")
    (tmp_path / "csv.toml").write_text(
        """
system = "bearing"
[files]
glob = "*.csv"
name = '^(?P<state>healthy|outer)_'
[states]
healthy = "healthy"
outer = "outer_race"
[signal]
key = '^accel$'
unit = "m/s^2"
[sampling_rate]
hz = 12000
[shaft_speed]
rpm = 1750
[load]
hp = 2
[geometry]
known = "cwru_drive_end"
"""
    )
    ds = read_records(folder, tmp_path / "csv.toml")
    assert list(np.unique(ds.state.values)) == ["healthy", "outer_race"]
    assert set(ds.shaft_speed.values) == {1750.0} and set(ds.load_hp.values) == {2.0}
    assert math.isnan(float(ds.sel(run=ds.state.values == "outer_race").fault_size_in[0]))
    stored = np.loadtxt(folder / "healthy_a.csv", delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_array_equal(ds.acceleration.values[0, 0], stored)
    assert "system_settings" not in ds.attrs  # the default bearing at its default rate
    assert json.loads(ds.attrs["source"])["importer"] == "csv"


@pytest.mark.skipif(
    not (DATA / "Normal" / "Normal_0.mat").is_file(),
    reason=f"the CWRU records are not at {DATA.resolve()}",
)
def test_the_cwru_manifest_reads_every_record_as_the_data_center_states_it(tmp_path):
    # the manifest shipped with the package, read as a user's manifest file, against
    # import_cwru; and both against the files read here with scipy
    out = tmp_path / "manifest.nc"
    args = ["import", str(CWRU_MANIFEST), str(DATA), "--out", str(out)]
    assert runner.invoke(app, args).exit_code == 0
    import_cwru(DATA, tmp_path / "cwru.nc")
    ds = load_campaign(out)
    assert ds.identical(load_campaign(tmp_path / "cwru.nc"))
    assert "system_settings" not in ds.attrs
    assert system_of(ds).settings() == BearingSystem().settings()
    states = {"Normal": "healthy", "IR": "inner_race", "OR": "outer_race", "B": "ball"}
    files = sorted(DATA.rglob("*.mat"))
    assert sorted(np.unique(ds.record.values)) == sorted(p.stem for p in files)
    for path in files:
        raw = scipy.io.loadmat(path)
        (key,) = [k for k in raw if k.endswith("_DE_time")]
        x = raw[key].ravel() * G
        runs = ds.sel(run=ds.record.values == path.stem)
        segments = x.size // 12000
        assert runs.sizes["run"] == segments
        np.testing.assert_array_equal(
            runs.acceleration.values[:, 0], x[: segments * 12000].reshape(segments, 12000)
        )
        rpm = [float(raw[k].ravel()[0]) for k in raw if k.endswith("RPM")]
        assert set(runs.shaft_speed.values) == set(rpm or [1797.0])
        code = re.match("[A-Za-z]+", path.stem)[0]
        assert set(runs.state.values) == {states[code]}
        assert set(runs.load_hp.values) == {float(path.stem[-1])}


def _rig_manifest(tmp_path, old: str, new: str) -> Path:
    path = tmp_path / "bad.toml"
    assert old in RIG_MANIFEST
    path.write_text(RIG_MANIFEST.replace(old, new))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("key = '^acc_g$'\n", "", r"bad\.toml: \[signal\] key is missing: a regular expression"),
        (
            'O = "outer_race"',
            'O = "outer"',
            r"\[states\] O: expected a state of bearing: healthy, inner_race, outer_race, ball, "
            r"got 'outer'",
        ),
        ('unit = "g"', 'unit = "gee"', r"\[signal\] unit: expected one of m/s\^2, .*g, mg"),
        ("[runs]", "[runs]\nsegment = 1.0", r"unknown key\(s\) segment in \[runs\]"),
        (f"hz = {FS}", "hz = 8000", r"\[sampling_rate\] campaign_hz: expected a rate the bearing"),
        (f"hz = {FS}", "", r"\[sampling_rate\] needs one of hz .* and candidates_hz"),
        ("n_balls = 12", "n_balls = 12.5", r"\[geometry\] n_balls: expected the number of rolling"),
        ("(?P<state>O)", "(?P<state>O", r"\[files\] name\[1\]: expected a regular expression"),
        ('glob = "*.mat"', 'glob = "*.wav"', r"\[files\] format: expected one of mat, npz, csv"),
        ('system = "bearing"', 'system = "door"', r"system: expected 'bearing'"),
        ("[signal]", "[signals]", r"unknown key\(s\) signals in the top level: allowed name"),
        ("[geometry]\n", "", r"bad\.toml: no \[geometry\] table \(a manifest needs \[files\], "),
    ],
)
def test_a_bad_manifest_names_the_key_and_writes_nothing(rig, tmp_path, old, new, message):
    folder, _ = rig
    manifest = _rig_manifest(tmp_path, old, new)
    with pytest.raises(ManifestError, match=message):
        read_manifest(manifest)
    out = tmp_path / "out.nc"
    with pytest.raises(ManifestError, match=message):
        import_records(manifest, folder, out)
    assert not out.exists()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            'glob = "*.mat"',
            'glob = "data/*.mat"',
            r"rig holds no \.mat files matching 'data/\*\.mat'",
        ),
        ('N = "healthy"\n', "", r"N_L0\.mat: its name's state code 'N' is none of the manifest's"),
        (
            "key = '^acc_g$'",
            "key = '^acc$'",
            r"N_L0\.mat: no \^acc\$ key \(keys: acc_g, speed_rpm\)",
        ),
        ("at_load = { 2 = 1720.0 }", "at_load = { 3 = 1720.0 }", r"O021_L2\.mat: no usable"),
    ],
)
def test_records_the_manifest_does_not_fit_leave_the_old_file(rig, tmp_path, old, new, message):
    folder, _ = rig
    manifest = _rig_manifest(tmp_path, old, new)
    out = tmp_path / "out.nc"
    out.write_bytes(b"the previous campaign")
    result = runner.invoke(
        app, ["import", str(manifest), str(folder), "--out", str(out), "--force"]
    )
    assert result.exit_code == 2
    assert re.search(message, " ".join(result.output.split())), result.output
    assert out.read_bytes() == b"the previous campaign"


def test_the_command_refuses_a_manifest_it_cannot_use(rig, tmp_path):
    folder, _ = rig
    out = tmp_path / "out.nc"
    cases = {
        tmp_path / "missing.toml": "missing.toml: no such manifest file",
        tmp_path / "broken.toml": "broken.toml: not TOML",
        tmp_path / "nosystem.toml": 'the manifest names no system (a line system = "NAME"',
        tmp_path / "door.toml": "no reader of manifests of the system 'elevator_door'",
    }
    (tmp_path / "broken.toml").write_text("name = [")
    (tmp_path / "nosystem.toml").write_text('name = "x"\n')
    (tmp_path / "door.toml").write_text('system = "elevator_door"\n')
    for manifest, message in cases.items():
        result = runner.invoke(app, ["import", str(manifest), str(folder), "--out", str(out)])
        assert result.exit_code == 2 and message in " ".join(result.output.split()), result.output
        assert not out.exists()


def test_campaign_settings_the_system_refuses_are_a_problem(rig):
    folder, manifest = rig
    ds = read_records(folder, manifest)
    ds.attrs["system_settings"] = json.dumps({"sampling_rate_hz": 8000.0})
    problems = validate_campaign(ds)
    assert [p.code for p in problems] == ["bad_system_settings"]
    assert "sampling_rate_hz=8000.0" in problems[0].message
    ds.attrs["system_settings"] = "{not json"
    assert [p.code for p in validate_campaign(ds)] == ["bad_system_settings"]
    with pytest.raises(ValueError, match="is not JSON"):
        system_of(ds)


def test_the_manifest_of_the_docs_is_one_the_reader_takes():
    page = (Path(__file__).parents[1] / "docs" / "bearing.md").read_text()
    (block,) = re.findall(r"^```toml\n(.*?)^```", page, flags=re.S | re.M)
    manifest = parse_manifest(block, source="docs/bearing.md")
    assert manifest.rate_hz == FS and manifest.campaign_rate_hz == FS
    assert manifest.states == {"N": "healthy", "O": "outer_race", "I": "inner_race"}
    assert manifest.geometry.orders()["bpfo"] == pytest.approx(BPFO_ORDER, rel=1e-12)
    assert manifest.names[1].search("O014_L1")["size"] == "014"
