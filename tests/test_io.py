"""Campaign files: construction, validation with specific messages, NetCDF and CSV round trips,
atomic writes that never overwrite by accident, and loads that never touch the file."""

import hashlib

import numpy as np
import pytest
import xarray as xr

from bayesdoor.io import (
    SIDECAR,
    CampaignError,
    check_campaign,
    from_csv,
    load_campaign,
    make_campaign,
    save_campaign,
    to_csv,
    validate_campaign,
)

DOOR = ["A1X", "A1Z", "A2X", "A2Z"]
FS = 2048.0


def _campaign(n_time=2048, fs=FS, window=True, seed=0):
    rng = np.random.default_rng(seed)
    return make_campaign(
        0.1 * rng.standard_normal((3, 4, n_time)),
        channels=DOOR,
        fs=fs,
        state=["healthy", "D1", "D2"],
        system="elevator_door",
        v_max=[0.3, 0.4, 0.5],
        split=["calibration", "test", "test"],
        t_start=[0.25, 0.25, 0.3] if window else None,
        t_stop=[0.75, 0.8, 0.9] if window else None,
        d2_depth=np.array([0.0, 0.0, 1.5e-4]),
    )


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _with_acceleration(ds, edit):
    acc = ds.acceleration.values.copy()
    edit(acc)
    return ds.copy(data={"acceleration": acc})


def _swap_times(ds):
    t = ds.time.values.copy()
    t[[100, 101]] = t[[101, 100]]
    return ds.assign_coords(time=("time", t, ds.time.attrs))


def _set_units(ds, units):
    ds = ds.copy()
    ds.attrs["units"] = units
    ds.acceleration.attrs["units"] = units
    return ds


def _without_attr(ds, name):
    ds = ds.copy()
    del ds.attrs[name]
    return ds


def _nan_and_inf(acc):
    acc[1, 1, [5, 6, 7]] = np.nan
    acc[1, 1, 9] = np.inf


# (case, bad dataset, validation options, expected problem codes, phrases the message must hold)
BAD_CASES = [
    (
        "missing_channel",
        lambda: _campaign().isel(channel=[0, 1, 2]),
        {"channels": DOOR},
        ["missing_channels"],
        ["channels ['A2Z'] are missing", "expected ['A1X', 'A1Z', 'A2X', 'A2Z']"],
    ),
    (
        "unknown_channel",
        lambda: _campaign(),
        {"channels": ["A1X", "A1Z", "A2X"]},
        ["unknown_channels"],
        ["channels ['A2Z'] are not expected", "rename or drop"],
    ),
    (
        "missing_sampling_rate",
        lambda: _without_attr(_campaign(), "sampling_rate_hz"),
        {},
        ["missing_sampling_rate"],
        ["attrs['sampling_rate_hz'] is missing"],
    ),
    (
        "rate_against_time",
        lambda: _campaign().assign_attrs(sampling_rate_hz=1000.0),
        {},
        ["sampling_rate_mismatch"],
        ["sampling_rate_hz is 1000 Hz but the time coordinate is spaced for 2048 Hz"],
    ),
    (
        "unexpected_rate",
        lambda: _campaign(fs=1024.0),
        {"sampling_rate_hz": FS},
        ["unexpected_sampling_rate"],
        ["sampling_rate_hz is 1024 Hz but 2048 Hz is expected"],
    ),
    (
        "non_finite",
        lambda: _with_acceleration(_campaign(), _nan_and_inf),
        {},
        ["non_finite"],
        ["run 1, channel A1Z: 3 NaN and 1 Inf samples of 2048"],
    ),
    (
        "clipped",
        lambda: _with_acceleration(
            _campaign(), lambda a: a.__setitem__((2, 2), np.clip(a[2, 2], -0.05, 0.05))
        ),
        {},
        ["clipped"],
        ["run 2, channel A2X:", "samples sit at exactly +-0.05 m/s^2", "saturated"],
    ),
    (
        "flat",
        lambda: _with_acceleration(_campaign(), lambda a: a.__setitem__((0, 3), 0.0)),
        {},
        ["flat"],
        ["run 0, channel A2Z: all 2048 samples equal 0.0", "dead"],
    ),
    (
        "too_short",
        lambda: _campaign(n_time=300, window=False),
        {},
        ["too_short"],
        ["300 samples (0.1465 s at 2048 Hz), fewer than the 512", "nperseg=512"],
    ),
    (
        "too_short_for_min_duration",
        lambda: _campaign(window=False),
        {"min_duration_s": 1.5},
        ["too_short"],
        ["2048 samples (1 s at 2048 Hz), fewer than the 3072"],
    ),
    (
        "non_monotonic_time",
        lambda: _swap_times(_campaign()),
        {},
        ["non_monotonic_time"],
        ["time is not strictly increasing", "the first at index 101"],
    ),
    (
        "units_g",
        lambda: _set_units(_campaign(), "g"),
        {},
        ["wrong_units", "wrong_units"],
        ["['units'] is 'g'", "multiplying by 9.80665"],
    ),
    (
        "units_unknown",
        lambda: _set_units(_campaign(), "V"),
        {},
        ["wrong_units", "wrong_units"],
        ["['units'] is 'V'", "accepted spellings"],
    ),
    (
        "missing_units",
        lambda: _without_attr(_campaign(), "units"),
        {},
        ["missing_units"],
        ["attrs['units'] is missing"],
    ),
    (
        "unknown_state",
        lambda: _campaign().assign_coords(state=("run", ["healthy", "D1", "D3"])),
        {},
        ["unknown_state"],
        ["run 2: state 'D3' is not one of"],
    ),
    (
        "missing_v_max",
        lambda: _campaign().drop_vars("v_max"),
        {},
        ["missing_v_max"],
        ["v_max (commanded peak speed, m/s) is missing"],
    ),
    (
        "nan_v_max",
        lambda: _campaign().assign_coords(v_max=("run", [0.3, np.nan, 0.5])),
        {},
        ["missing_v_max"],
        ["v_max is missing (not finite) for runs [1]"],
    ),
    (
        "unknown_split",
        lambda: _campaign().assign_coords(split=("run", ["calibration", "train", "test"])),
        {},
        ["unknown_split"],
        ["run 1: split 'train'"],
    ),
    (
        "motion_window_too_short",
        lambda: _campaign().assign_coords(t_stop=("run", [0.75, 0.3, 0.9])),
        {},
        ["window_too_short"],
        ["run 1: the motion window [0.25, 0.3] s spans about 103 samples", "nperseg=512"],
    ),
]


@pytest.mark.parametrize(
    "make_bad, options, codes, phrases",
    [case[1:] for case in BAD_CASES],
    ids=[case[0] for case in BAD_CASES],
)
def test_bad_file_gets_its_own_message_and_stays_untouched(
    tmp_path, make_bad, options, codes, phrases
):
    path = tmp_path / "bad.nc"
    make_bad().to_netcdf(path, engine="h5netcdf")
    before = _sha(path)
    with pytest.raises(CampaignError) as err:
        load_campaign(path, **options)
    assert [p.code for p in err.value.problems] == codes
    assert str(path) in str(err.value)
    for phrase in phrases:
        assert phrase in str(err.value)
    assert _sha(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.nc"]


def test_messages_differ_between_cases():
    messages = [
        tuple(p.message for p in validate_campaign(make_bad(), **options))
        for _, make_bad, options, _, _ in BAD_CASES
    ]
    assert len(set(messages)) == len(BAD_CASES)


def test_problems_name_run_and_channel():
    bad = _with_acceleration(_campaign(), _nan_and_inf)
    (problem,) = validate_campaign(bad)
    assert (problem.run, problem.channel) == (1, "A1Z")


def test_valid_campaign_has_no_problems():
    assert validate_campaign(_campaign(), channels=DOOR, sampling_rate_hz=FS) == []
    check_campaign(_campaign(), channels=DOOR, sampling_rate_hz=FS)


def test_not_a_campaign():
    ds = xr.Dataset({"signal": (("run", "time"), np.zeros((2, 600)))})
    (problem,) = validate_campaign(ds)
    assert problem.code == "no_acceleration"
    assert "variables: ['signal']" in problem.message


def test_accepted_spellings_of_units():
    for units in ("m/s^2", "m s-2", "m/s**2"):
        assert validate_campaign(_set_units(_campaign(), units)) == []


def _quantised_sine(f, bits):
    t = np.arange(7168) / FS
    q = 2 ** (bits - 1) - 1
    return np.round(np.sin(2 * np.pi * f * t + 0.3) * q) / q


@pytest.mark.parametrize(
    "make_signal",
    [
        lambda rng: rng.standard_normal(7168),
        lambda rng: (
            np.sin(2 * np.pi * 25 * np.arange(7168) / FS) + 0.01 * rng.standard_normal(7168)
        ),
        lambda rng: _quantised_sine(4.0, 12),
        lambda rng: _quantised_sine(25.0, 12),
        lambda rng: _quantised_sine(25.0, 16),
        lambda rng: (
            np.round((_quantised_sine(25.0, 16) + 0.003 * rng.standard_normal(7168)) * 2047) / 2047
        ),
        lambda rng: np.exp(-np.arange(7168) / 300.0) * np.sin(np.arange(7168) / 5.0),
    ],
    ids=[
        "noise",
        "sine_noise",
        "sine_12bit_4Hz",
        "sine_12bit",
        "sine_16bit",
        "noisy_12bit",
        "decay",
    ],
)
def test_normal_signals_are_not_clipped(make_signal):
    x = make_signal(np.random.default_rng(1))
    ds = make_campaign(
        np.broadcast_to(x, (1, 4, x.size)),
        channels=DOOR,
        fs=FS,
        state=["healthy"],
        system="elevator_door",
        v_max=[0.3],
    )
    assert validate_campaign(ds) == []


def test_short_clipping_bursts_are_caught_by_their_number():
    # impacts saturate for 3 samples at a time (below clip_run) but 60 times (2.9 % of 2048)
    x = 0.1 * np.random.default_rng(2).standard_normal(2048)
    for start in range(10, 2048 - 3, 34):
        x[start : start + 3] = 1.0
    ds = make_campaign(
        x[None, None], channels=["A1X"], fs=FS, state=["D1"], system="elevator_door", v_max=[0.3]
    )
    (problem,) = validate_campaign(ds)
    assert problem.code == "clipped"
    assert "longest stretch 3 samples" in problem.message


def test_netcdf_round_trip_is_exact(tmp_path):
    ds = _campaign()
    ds.attrs["campaign"] = "bench 7"
    ds.attrs["gain"] = np.float64(1.25)
    ds.channel.attrs["sensor"] = "PCB 356A"
    path = save_campaign(ds, tmp_path / "c.nc")
    back = load_campaign(path, channels=DOOR, sampling_rate_hz=FS)
    assert back.identical(ds)
    np.testing.assert_array_equal(back.acceleration.values, ds.acceleration.values)
    assert back.acceleration.dtype == np.float64


def test_csv_round_trip_is_exact(tmp_path):
    # repr() writes the shortest decimal that parses back to the same float: no tolerance
    ds = _campaign()
    ds.attrs["campaign"] = "bench 7"
    ds.attrs["gains"] = np.array([1.0, 1.5])
    ds = ds.assign_coords(
        temperature=("run", [21.5, np.nan, np.inf]),
        sensor=("channel", ["a", "b", "c", "d"], {"note": "serials"}),
    )
    tiny = _with_acceleration(ds, lambda a: a.__setitem__((0, 0, 0), 1e-300))
    paths = to_csv(tiny, tmp_path / "csv")
    assert [p.name for p in paths] == ["run_0000.csv", "run_0001.csv", "run_0002.csv", SIDECAR]
    back = from_csv(tmp_path / "csv")
    assert back.identical(tiny)
    lines = (tmp_path / "csv" / "run_0001.csv").read_text().splitlines()
    assert lines[0] == "time,A1X,A1Z,A2X,A2Z"
    assert len(lines) == 1 + 2048


def test_csv_without_sidecar_uses_arguments_and_pads(tmp_path):
    ds = _campaign(window=False)
    to_csv(ds, tmp_path)
    short = tmp_path / "run_0002.csv"
    lines = short.read_text().splitlines()
    short.write_text("\n".join(lines[:1001]) + "\n")
    files = [tmp_path / f"run_{i:04d}.csv" for i in range(3)]
    back = from_csv(
        files, system="elevator_door", state=["healthy", "D1", "D2"], v_max=[0.3, 0.4, 0.5]
    )
    assert back.attrs["sampling_rate_hz"] == FS
    np.testing.assert_array_equal(back.time.values, ds.time.values)
    np.testing.assert_array_equal(back.acceleration.values[:2], ds.acceleration.values[:2])
    np.testing.assert_array_equal(
        back.acceleration.values[2, :, :1000], ds.acceleration.values[2, :, :1000]
    )
    assert np.all(back.acceleration.values[2, :, 1000:] == 0.0)
    assert list(back.state.values) == ["healthy", "D1", "D2"]


def test_csv_with_rounded_time_stamps(tmp_path):
    # an acquisition system that writes its time column in microseconds
    ds = _campaign(window=False)
    to_csv(ds, tmp_path)
    files = sorted(tmp_path.glob("*.csv"))
    for path in files:
        lines = path.read_text().splitlines()
        rows = [ln.split(",", 1) for ln in lines[1:]]
        path.write_text("\n".join([lines[0], *(f"{float(t):.6f},{r}" for t, r in rows)]) + "\n")
    back = from_csv(files, system="elevator_door", v_max=[0.3, 0.4, 0.5])
    check_campaign(back, sampling_rate_hz=FS)
    # (n - 1) / (last - first time): the last stamp is off by at most 0.5 us in 1 s
    assert abs(back.attrs["sampling_rate_hz"] / FS - 1.0) < 1e-6
    np.testing.assert_array_equal(back.acceleration.values, ds.acceleration.values)


def test_csv_without_v_max_is_reported(tmp_path):
    to_csv(_campaign(), tmp_path)
    files = sorted(tmp_path.glob("*.csv"))
    with pytest.raises(
        CampaignError, match=r"v_max is missing \(not finite\) for runs \[0, 1, 2\]"
    ):
        from_csv(files, system="elevator_door")
    ds = from_csv(files, check=False)
    assert list(ds.state.values) == ["unknown"] * 3


def test_csv_with_channels_reorders_and_refuses_missing(tmp_path):
    to_csv(_campaign(), tmp_path)
    files = sorted(tmp_path.glob("*.csv"))
    ds = from_csv(files, channels=["A2Z", "A1X"], system="elevator_door", v_max=[0.3, 0.4, 0.5])
    np.testing.assert_array_equal(
        ds.acceleration.values, _campaign().acceleration.values[:, [3, 0]]
    )
    with pytest.raises(CampaignError, match=r"missing \['B1X'\]"):
        from_csv(files, channels=["A1X", "B1X"])


@pytest.mark.parametrize(
    "edit, phrase",
    [
        (lambda lines: [*lines[:5], "0.1,0.2,0.3", *lines[6:]], "unreadable CSV"),
        (lambda lines: ["t,A1X,A1Z,A2X,A2Z", *lines[1:]], "no 'time' column"),
        (lambda lines: ["time,A1X,A1Z,A2X,B2Z", *lines[1:]], "differ from"),
        (lambda lines: lines[:1], "no data rows"),
        (
            lambda lines: [lines[0], *(ln.replace("0.0009765625,", "0.002,") for ln in lines[1:])],
            "time[2] = 0.002 s",
        ),
    ],
    ids=["ragged_row", "no_time", "other_channels", "empty", "other_time_grid"],
)
def test_bad_csv_is_refused_and_untouched(tmp_path, edit, phrase):
    to_csv(_campaign(), tmp_path)
    bad = tmp_path / "run_0001.csv"
    bad.write_text("\n".join(edit(bad.read_text().splitlines())) + "\n")
    before = _sha(bad)
    with pytest.raises(CampaignError, match=r"run_0001\.csv") as err:
        from_csv(tmp_path)
    assert phrase in str(err.value)
    assert _sha(bad) == before


def test_sidecar_and_arguments_together_are_refused(tmp_path):
    to_csv(_campaign(), tmp_path)
    with pytest.raises(ValueError, match=r"defines the metadata; got \['system', 'v_max'\]"):
        from_csv(tmp_path, system="elevator_door", v_max=[0.1, 0.2, 0.3])


def test_save_refuses_to_overwrite(tmp_path):
    path = save_campaign(_campaign(seed=0), tmp_path / "c.nc")
    before = _sha(path)
    with pytest.raises(FileExistsError, match=r"c\.nc already exists; pass overwrite=True"):
        save_campaign(_campaign(seed=1), path)
    assert _sha(path) == before
    save_campaign(_campaign(seed=1), path, overwrite=True)
    assert load_campaign(path).identical(_campaign(seed=1))


def test_to_csv_refuses_to_overwrite(tmp_path):
    to_csv(_campaign(seed=0), tmp_path)
    before = {p.name: _sha(p) for p in tmp_path.iterdir()}
    with pytest.raises(FileExistsError, match="pass overwrite=True"):
        to_csv(_campaign(seed=1), tmp_path)
    assert {p.name: _sha(p) for p in tmp_path.iterdir()} == before
    to_csv(_campaign(seed=1), tmp_path, overwrite=True)
    assert from_csv(tmp_path).identical(_campaign(seed=1))


def test_failed_write_leaves_old_file_and_no_temporary(tmp_path, monkeypatch):
    path = save_campaign(_campaign(), tmp_path / "c.nc")
    before = _sha(path)

    def half_written(self, target, **kwargs):
        with open(target, "wb") as f:
            f.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", half_written)
    with pytest.raises(OSError, match="disk full"):
        save_campaign(_campaign(seed=1), path, overwrite=True)
    assert _sha(path) == before
    assert [p.name for p in tmp_path.iterdir()] == ["c.nc"]


def test_unreadable_file_is_refused_and_untouched(tmp_path):
    path = tmp_path / "junk.nc"
    path.write_bytes(b"not a netcdf file\n" * 10)
    before = _sha(path)
    with pytest.raises(ValueError, match="not a readable NetCDF campaign file"):
        load_campaign(path)
    assert _sha(path) == before
    with pytest.raises(FileNotFoundError, match="no campaign file"):
        load_campaign(tmp_path / "missing.nc")


def test_make_campaign_refuses_bad_input():
    acc = np.zeros((2, 4, 600))
    kwargs = dict(
        channels=DOOR, fs=FS, state=["healthy", "D1"], system="elevator_door", v_max=[0.3, 0.4]
    )
    with pytest.raises(ValueError, match=r"4 channels \(shape \(2, 4, 600\)\) but 3 names"):
        make_campaign(acc, **{**kwargs, "channels": DOOR[:3]})
    with pytest.raises(ValueError, match=r"v_max needs one entry per run \(2\)"):
        make_campaign(acc, **{**kwargs, "v_max": [0.3]})
    with pytest.raises(ValueError, match=r"unknown state labels \['D4'\]"):
        make_campaign(acc, **{**kwargs, "state": ["healthy", "D4"]})
    with pytest.raises(ValueError, match=r"unknown split labels \['train'\]"):
        make_campaign(acc, **{**kwargs, "split": ["train", "test"]})
    with pytest.raises(ValueError, match="fs must be a positive sampling rate in Hz, got -1"):
        make_campaign(acc, **{**kwargs, "fs": -1.0})


def test_system_of_builds_a_system_once_per_name_and_factory():
    """A campaign's system is built on first use and the same object is returned after; a
    different factory registered under the name builds anew; an unknown name gives None."""
    from bayesdoor.door import ElevatorDoor
    from bayesdoor.io import system_of
    from bayesdoor.systems import register_system

    built = []

    def factory():
        built.append(ElevatorDoor())
        return built[-1]

    register_system("door_built_once", factory)
    campaign = xr.Dataset(attrs={"system": "door_built_once"})
    assert system_of(campaign) is system_of("door_built_once") is built[0]
    assert len(built) == 1
    register_system("door_built_once", lambda: factory())
    assert system_of(campaign) is built[1] and len(built) == 2
    assert system_of("no_such_system") is None
