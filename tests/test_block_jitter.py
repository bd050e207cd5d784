"""CK jitter on the synthetic block's TRUTH kernels (issue 30, item 4) and the jitter spectra of the run report
(item 5): the truth cameras loaded through SPICE carry the simulated sinusoid (oracle: the block model's smooth
attitude and the closed-form sinusoid), the navigation cameras do not; the amplitude spectrum of a sinusoid
peaks at its frequency with its amplitude (closed form); a shot table with a missing column given to
``lunarmap run`` is named before any work, nothing written."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.cli import main
from lunarmap.errors import InvalidInputError
from lunarmap.evaluate.jitter import amplitude_spectrum, spectrum_peak
from lunarmap.orientation.rotation import matrix_to_rotvec
from lunarmap.simulate import block_cameras
from lunarmap.simulate.block_jitter import add_block_jitter, block_jitter_truth
from lunarmap.synthetic import write_block_mission

AMPLITUDE, FREQUENCY = 3e-6, 8.0


@pytest.fixture(scope="module")
def jittered(tmp_path_factory):
    folder = tmp_path_factory.mktemp("block_jitter")
    bm = write_block_mission(folder / "mission", seed=0)
    add_block_jitter(bm, [(AMPLITUDE, FREQUENCY)], seed=0)
    return bm


def _attitude_offset(cam, bm, naif_id, t):
    """Rotation vector (sensor frame) of the camera's attitude relative to the block model's smooth one."""
    rt = np.swapaxes(cam.eo.rotation_at(t), -1, -2)                       # body -> sensor, the camera's
    return matrix_to_rotvec(rt @ bm.model.sensor_to_body(naif_id, cam.eo.epoch + t))


@pytest.mark.parametrize("name", ["orbit1_nac", "orbit2_tc"])
def test_truth_cameras_carry_the_jitter_and_navigation_cameras_do_not(jittered, name):
    bm = jittered
    naif = int(bm.model.image(name).camera.naif_id)
    truth, nav = block_cameras(bm, "truth", [name])[name], block_cameras(bm, "navigation", [name])[name]
    t = np.linspace(truth.eo.times[0], truth.eo.times[-1], 400)
    # closed form: the sinusoid of the phases written beside the kernels, turned into the sensor frame
    jt = block_jitter_truth(bm.folder)
    ph = jt.phases[0]
    expect = AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * (truth.eo.epoch + t - jt.t0)[:, None] + ph[None, :])
    expect = expect @ bm.model.mounting(naif).T
    got = _attitude_offset(truth, bm, naif, t)
    got = got - got.mean(axis=0)                    # a constant (aberration, sampling) is not the jitter
    expect = expect - expect.mean(axis=0)
    assert np.sqrt(np.mean((got - expect) ** 2)) < 0.02 * AMPLITUDE
    assert np.all(np.std(expect, axis=0) > 0.3 * AMPLITUDE)
    # the navigation's attitude differs from the smooth truth by its bias and drift only: no 8 Hz left
    nv = _attitude_offset(nav, bm, naif, t)
    lin = np.polynomial.polynomial.polyfit(t, nv, 2)
    resid = nv - np.polynomial.polynomial.polyval(t, lin).T
    assert np.sqrt(np.mean(resid ** 2)) < 0.01 * AMPLITUDE


def test_amplitude_spectrum_of_a_sinusoid():
    dt, n = 6.5e-4, 512
    t = np.arange(n) * dt
    # a whole number of periods over the record: the peak has the sinusoid's amplitude exactly
    f0 = 11 / (n * dt)
    x = np.column_stack([2e-6 * np.sin(2 * np.pi * f0 * t + 0.3), np.zeros(n)])
    f, a = amplitude_spectrum(x, dt)
    pk_f, pk_a = spectrum_peak(f, a[:, 0])
    assert pk_f == pytest.approx(f0, rel=1e-12) and pk_a == pytest.approx(2e-6, rel=1e-9)
    # between: on the zero-padded grid, the peak's frequency exact and its amplitude within the leakage of the
    # negative-frequency image (~1 / (2 pi k) for k periods)
    f1 = 45 / (4 * n * dt)
    f, a1 = amplitude_spectrum(2e-6 * np.sin(2 * np.pi * f1 * t + 0.3), dt)
    pk_f, pk_a = spectrum_peak(f, a1)
    assert pk_f == pytest.approx(f1, rel=1e-12) and pk_a == pytest.approx(2e-6, rel=0.03)
    assert np.max(a[:, 1]) == 0.0
    with pytest.raises(InvalidInputError):
        amplitude_spectrum(x[:3], dt)
    with pytest.raises(InvalidInputError):
        amplitude_spectrum(x, 0.0)


def test_bad_jitter_waves_are_named(jittered, tmp_path):
    with pytest.raises(InvalidInputError, match="waves"):
        add_block_jitter(jittered, [(-1e-6, 5.0)])
    with pytest.raises(InvalidInputError, match="does not resolve"):
        add_block_jitter(jittered, [(1e-6, 100.0)], step=0.002)


def test_run_with_a_shot_table_missing_a_column_names_it_before_any_work(jittered, tmp_path, capsys):
    """A run configuration whose ``[[adjust.terrain.altimetry]]`` table lacks ``radius``: a named
    AltimetryInputError from the command line, before any step; no store entry, no outputs."""
    bm = jittered
    (tmp_path / "shots.csv").write_text("track,time,lon,lat\nT0,0.0,161.5,57.0\nT0,1.0,161.5,57.001\n")
    images = "".join(f'[[images]]\nname = "{n}"\nlabel = "{bm.folder / (n + ".lbl")}"\n'
                     f'pixels = "{tmp_path / (n + ".nc")}"\n' for n in ("orbit1_nac", "orbit2_nac"))
    import xarray as xr

    for n in ("orbit1_nac", "orbit2_nac"):       # a readable image header; its pixels are never read
        xr.DataArray(np.zeros((512, 512), np.float32), dims=("line", "sample")).to_netcdf(tmp_path / f"{n}.nc")
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'[run]\noutput = "run"\n\n[kernels]\nmetakernel = "{bm.folder / "navigation.tm"}"\n\n{images}\n'
                   '[adjust]\ndegree = 1\n\n[adjust.navigation]\nposition_sigma = 0.5\nattitude_sigma = 1e-6\n\n'
                   '[adjust.terrain]\n[[adjust.terrain.altimetry]]\npath = "shots.csv"\n'
                   'sigma = 0.5\n')
    assert main(["run", str(cfg), "--serial"]) == 2
    err = capsys.readouterr().err
    assert "AltimetryInputError" in err and "shots.csv" in err and "radius" in err
    store = tmp_path / "run" / "store"
    assert not (tmp_path / "run" / "outputs").exists()
    assert not (store.exists() and [p for p in store.rglob("*") if p.is_file()])
