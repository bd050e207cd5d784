"""The readers of outside files that are fuzzed, each with the real files it starts from.

:func:`build_targets` writes the seed files (a synthetic mission and everything lunarmap writes
itself: RPC text and netCDF, BAL, control networks, tie-point tables, ISDs, an ISIS cube with
``spiceinit``-style tables) into a folder and adds the real labels, meta-kernels, cube and ALE
ISD of the shared kernel sets when they are present. Every target's ``call`` reads the input and
then uses what it read one step further (projects a point through a model, converts a network
into observations, builds the camera of an ISD), because a reader that accepts a file it should
have refused only fails later.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

from fuzzhelp import Seed, Target

__all__ = ["READERS", "build_targets", "shared_kernels"]

#: reader name -> the targets that exercise it (image_support: one target per kernel set, so that
#: a target's inputs never reload SPICE kernels).
READERS = {
    "pvl_label": ["pvl_label"],
    "isis_table": ["isis_table"],
    "meta_kernel": ["meta_kernel"],
    "rpc_txt": ["rpc_txt"],
    "rpc_netcdf": ["rpc_netcdf"],
    "bal": ["bal", "bal_meta"],
    "network": ["network"],
    "tiepoints": ["tiepoints"],
    "isd_json": ["isd_json"],
    "image_support": ["image_support_synthetic", "image_support_lro", "image_support_kaguya",
                      "image_support_clementine", "image_support_other"],
    "image_list": ["image_list"],
    # issue 28: the readers added since the first fuzzing
    "isis_cube": ["isis_cube"],
    "pds3_image": ["pds3_image"],
    "geotiff": ["geotiff"],
    "isis_network": ["isis_network_v5"],
    "isis_network_v2": ["isis_network_v2"],
    "isis_network_pvl": ["isis_network_pvl"],
    "cube_camera": ["cube_camera_lro"],
    "run_config": ["run_config"],
}


def shared_kernels() -> Path | None:
    root = Path(__file__).resolve().parents[1]
    folder = Path(os.environ.get("LUNARMAP_SHARED_KERNELS", root.parent / "shared" / "data" / "kernels"))
    return folder if folder.is_dir() else None


# --- seed writers -----------------------------------------------------------------------------------

def _absolute_metakernel(text: str, folder: Path) -> str:
    """The meta-kernel with its relative PATH_VALUES made absolute, so a copy anywhere still loads."""
    def repl(m: re.Match) -> str:
        vals = re.findall(r"'([^']*)'", m.group(2))
        fixed = " ".join(f"'{v if os.path.isabs(v) else (folder / v).resolve()}'" for v in vals)
        return f"{m.group(1)}( {fixed} )"

    return re.sub(r"(PATH_VALUES\s*=\s*)\(([^)]*)\)", repl, text)


def isis_cube_bytes(tables: dict[str, dict[str, np.ndarray]], lines: int = 100, samples: int = 50) -> bytes:
    """A small ISIS cube: attached PVL label with ``Object = Table`` blocks, then the tables' records."""
    type_names = {"f8": "Double", "i4": "Integer", "f4": "Real"}
    blobs, objects = [], []
    for name, cols in tables.items():
        dtype = np.dtype([(k, v.dtype.str, v.shape[1:]) if v.ndim > 1 else (k, v.dtype.str) for k, v in cols.items()])
        n = len(next(iter(cols.values())))
        rec = np.empty(n, dtype=dtype)
        for k, v in cols.items():
            rec[k] = v
        fields = "\n".join(
            f"  Group = Field\n    Name = {k}\n    Type = {type_names[v.dtype.str[1:]]}\n"
            f"    Size = {int(np.prod(v.shape[1:])) if v.ndim > 1 else 1}\n  End_Group" for k, v in cols.items())
        blobs.append(rec.tobytes())
        objects.append((name, n, len(blobs[-1]), fields))
    head_size = 4096
    body, pos = [], head_size + 1
    for (name, n, nbytes, fields), blob in zip(objects, blobs):
        body.append(f"Object = Table\n  Name = {name}\n  StartByte = {pos}\n  Bytes = {nbytes}\n  Records = {n}\n"
                    f"  ByteOrder = Lsb\n  TimeDependentFrames = (31006, 1)\n{fields}\nEnd_Object\n")
        pos += nbytes
    label = (f"Object = IsisCube\n  Object = Core\n    Group = Dimensions\n      Samples = {samples}\n"
             f"      Lines = {lines}\n      Bands = 1\n    End_Group\n  End_Object\nEnd_Object\n" + "".join(body)
             + "End\n").encode()
    assert len(label) < head_size
    return label + b"\0" * (head_size - len(label)) + b"".join(blobs)


def _rfm_seed(folder: Path):
    from lunarmap.rpc import RationalFunctionModel

    c = np.zeros((4, 20))
    c[0, [0, 2, 1, 3]] = [0.1, 0.9, 0.02, 0.01]
    c[1, [0, 3]] = [1.0, 0.05]
    c[2, [1, 2, 3]] = [1.0, -0.03, 0.2]
    c[3, [0, 3, 1]] = [1.0, 0.05, 0.01]
    rng = np.random.default_rng(5)
    c[:, 4:] += rng.normal(0, 1e-4, (4, 16))
    return RationalFunctionModel(c, [26112.0, 2532.0, 10.0, 179.9, 500.0], [26112.0, 2532.0, 0.4, 0.2, 11000.0],
                                 n_lines=52224, n_samples=5064, attrs={"note": "fuzz seed"})


def _geoeye_text(model) -> str:
    """The same model in the GeoEye/DigitalGlobe spelling: ``KEY=value units``, signs and zero padding."""
    from lunarmap.rpc import rpc_txt_keywords

    units = {"LINE_OFF": "pixels", "SAMP_OFF": "pixels", "LAT_OFF": "degrees", "LONG_OFF": "degrees",
             "HEIGHT_OFF": "meters"}
    return "".join(f"{k}={v:+.15E} {units.get(k, '')}\n" for k, v in rpc_txt_keywords(model).items())


def _network_seed():
    from lunarmap.adjust.network import ControlNetwork

    n = 6
    rng = np.random.default_rng(3)
    xyz = rng.normal(0, 1e3, (n, 3)) + [1.7374e6, 0, 0]
    xyz[:2] = np.nan
    cov = np.full((n, 3, 3), np.nan)
    cov[2:4] = np.eye(3) * 0.25
    return ControlNetwork(point_id=[f"P{i}" for i in range(n)], point_type=["tie", "tie", "control", "control",
                                                                            "check", "tie"],
                          xyz=np.where(np.arange(n)[:, None] == 5, xyz[0], xyz), measure_point=[0, 0, 1, 1, 2, 3, 4, 4, 5, 5],
                          measure_image=[0, 1, 0, 2, 1, 2, 0, 1, 1, 2], line_sample=rng.uniform(1, 500, (10, 2)),
                          measure_sigma=np.full((10, 2), 0.3), image_id=["M1L", "M2L", "M3R"],
                          xyz_cov=cov, attrs={"site": "fuzz"})


def _tiepoint_seed():
    import xarray as xr

    rng = np.random.default_rng(4)
    n = 12
    return xr.Dataset(
        {"point_id": ("observation", np.repeat(np.arange(6), 2).astype(np.int64)),
         "image_id": ("observation", np.tile([0, 1], 6).astype(np.int32)),
         "line": ("observation", rng.uniform(1, 500, n)), "sample": ("observation", rng.uniform(1, 500, n)),
         "sigma_line": ("observation", np.full(n, 0.05)), "sigma_sample": ("observation", np.full(n, 0.05)),
         "correlation": ("observation", np.full(n, 0.95))},
        coords={"image": ("image", np.array(["a", "b"]))}, attrs={"source": "lunarmap.matching"})


def _bal_seed():
    from lunarmap.adjust.bal import BALData

    rng = np.random.default_rng(6)
    cams = np.column_stack([rng.normal(0, 0.01, (4, 3)), rng.normal(0, 1, (4, 2)), np.full(4, -10.0),
                            np.full(4, 500.0), np.full(4, 1e-7), np.zeros(4)])
    pts = rng.normal(0, 1, (12, 3))
    ci, pi = np.repeat(np.arange(4), 12), np.tile(np.arange(12), 4)
    return BALData(cams, pts, ci, pi, rng.normal(0, 50, (48, 2)))


# --- calls: read, then use one step further ------------------------------------------------------

def _use_rfm(model) -> None:
    o = model.offsets
    line, samp = model.lonlat_to_image(o[3], o[2], o[4])
    model.image_to_lonlat(o[0], o[1], o[4])
    assert np.shape(line) == () and np.shape(samp) == ()


def _use_camera(cam) -> None:
    lines, samples = cam.n_lines, cam.n_samples
    xyz = cam.image_to_ground(np.array([lines / 2.0]), np.array([samples / 2.0]), 0.0, on_miss="nan")
    if np.all(np.isfinite(xyz)):
        cam.ground_to_image(xyz, on_miss="nan")


def call_pvl(path: Path, seed: Seed) -> None:
    from lunarmap.labels import load_label

    lab = load_label(path)
    lab.find("Lines")
    lab.all("Table")


def call_isis_table(path: Path, seed: Seed) -> None:
    from lunarmap.labels import isis_table_names, load_label, read_isis_table

    for name in isis_table_names(load_label(path)) or seed.context["tables"]:
        cols, _ = read_isis_table(path, name)
        assert all(isinstance(v, np.ndarray) for v in cols.values())


def call_meta_kernel(path: Path, seed: Seed) -> None:
    from lunarmap.spice import KernelSet

    kset = KernelSet.from_metakernel(path)
    assert all(os.path.isfile(p) for p in kset.paths)
    kset.fingerprint


def call_rpc_txt(path: Path, seed: Seed) -> None:
    from lunarmap.rpc import read_rpc_txt

    _use_rfm(read_rpc_txt(path))


def call_rpc_netcdf(path: Path, seed: Seed) -> None:
    from lunarmap.rpc import read_netcdf

    _use_rfm(read_netcdf(path))


def call_bal(path: Path, seed: Seed) -> None:
    from lunarmap.adjust.bal import bal_to_problem, read_bal

    data = read_bal(path)
    if data.cameras.shape[0] and data.points.shape[0]:
        bal_to_problem(data)


def call_bal_meta(path: Path, seed: Seed) -> None:
    """``path`` is the ``.meta.json`` sidecar of a good BAL file written beside it for the call."""
    from lunarmap.adjust.bal import bal_to_problem, read_bal

    bal = path.with_name(path.name[: -len(".meta.json")] + ".bal")
    bal.write_bytes(seed.context["bal"])
    try:
        bal_to_problem(read_bal(bal))
    finally:
        bal.unlink()


def call_network(path: Path, seed: Seed) -> None:
    from lunarmap.adjust.network import read_network

    net = read_network(path)
    net.observations()
    net.priors()


def call_tiepoints(path: Path, seed: Seed) -> None:
    from lunarmap.adjust.network import network_from_tiepoints
    from lunarmap.matching import read_tiepoints

    network_from_tiepoints(read_tiepoints(path))


def call_isd_json(path: Path, seed: Seed) -> None:
    from lunarmap.camera import camera_from_isd
    from lunarmap.orientation.isd import ImageSupport

    _use_camera(camera_from_isd(ImageSupport.read_json(path)))


def call_image_support(path: Path, seed: Seed) -> None:
    from lunarmap.camera import camera_from_isd
    from lunarmap.orientation.drivers import image_support
    from lunarmap.spice import ensure_loaded

    ensure_loaded(seed.context["kernels"])  # a no-op after prepare_kernels
    _use_camera(camera_from_isd(image_support(path, seed.context["kernels"])))


def prepare_kernels(seed: Seed) -> None:
    """Load the seed's kernel set before the input (SPICE keeps the kernel files open while loaded)."""
    from lunarmap.spice import ensure_loaded

    ensure_loaded(seed.context["kernels"])


def call_image_list(path: Path, seed: Seed) -> None:
    from workflows.isd_batch import read_image_list

    assert all(len(pair) == 2 for pair in read_image_list(path))


def _pixels_used(da) -> None:
    """Compute the pixels (every chunk: a damaged one fails here) and read a window through PixelSource."""
    # computed in this thread: with dask's thread pool, chunks still being read when another chunk's error
    # is raised would hold the file open past the call (counted as a leaked descriptor)
    values = da.data.compute(scheduler="sync")
    assert values.ndim == 3


def call_isis_cube(path: Path, seed: Seed) -> None:
    from lunarmap.io import IsisCube
    from lunarmap.io.window import PixelSource

    cube = IsisCube(path)
    _pixels_used(cube.pixels())
    src = PixelSource(path)
    src.read(0, min(3, src.shape[0]), 0, min(3, src.shape[1]))


def call_image(path: Path, seed: Seed) -> None:
    from lunarmap.io.raster import open_image
    from lunarmap.io.window import PixelSource

    _pixels_used(open_image(path, chunks=(8, 8)))
    src = PixelSource(path)
    src.read(0, min(3, src.shape[0]), 0, min(3, src.shape[1]))


def call_isis_network(path: Path, seed: Seed) -> None:
    from lunarmap.adjust.isis import read_isis_network

    net = read_isis_network(path)
    net.observations()


def call_cube_camera(path: Path, seed: Seed) -> None:
    from lunarmap.camera.cube import camera_from_cube

    _use_camera(camera_from_cube(path, image_size=seed.context.get("image_size")))


def call_run_config(path: Path, seed: Seed) -> None:
    from lunarmap.workflows.config import load_config

    cfg = load_config(path)
    cfg.digest()
    assert all(im.pixels.is_file() and im.label.is_file() for im in cfg.images)


def _pds3_bytes(lines: int = 20, samples: int = 16) -> bytes:
    data = (np.arange(lines * samples) % 700 - 50).astype(">i2").reshape(lines, samples)
    data[3, 4] = -32768
    prefix, record = 4, 4 + samples * 2 + 2
    label = ("PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\nRECORD_BYTES = %d\r\n^IMAGE = 16\r\n"
             "OBJECT = IMAGE\r\n  LINES = %d\r\n  LINE_SAMPLES = %d\r\n  SAMPLE_TYPE = MSB_INTEGER\r\n"
             "  SAMPLE_BITS = 16\r\n  LINE_PREFIX_BYTES = %d\r\n  LINE_SUFFIX_BYTES = 2\r\n  BANDS = 1\r\n"
             "  OFFSET = 10.0\r\n  SCALING_FACTOR = 0.5\r\n  MISSING_CONSTANT = -32768\r\nEND_OBJECT = IMAGE\r\n"
             "END\r\n") % (record, lines, samples, prefix)
    rows = b"".join(b"\x01\x02\x03\x04" + data[i].tobytes() + b"\0\0" for i in range(lines))
    head = label.encode()
    assert len(head) <= 15 * record
    return head.ljust(15 * record, b" ") + rows


def _geotiff_seeds(folder: Path) -> list[Seed]:
    try:
        import rasterio
    except ImportError:
        return []
    rng = np.random.default_rng(8)
    out = []
    for name, kw in (("tiled_deflate.tif", {"tiled": True, "blockxsize": 16, "blockysize": 16, "compress": "deflate"}),
                     ("strips.tif", {})):
        p = folder / name
        data = rng.normal(100, 20, (1, 40, 40)).astype(np.float32)
        with rasterio.open(p, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32", nodata=-9999.0,
                           **kw) as ds:
            ds.write(data)
        out.append(Seed(p.read_bytes(), ".tif", {}, name))
    return out


def _run_config_text(folder: Path, labels: list[Path], pixels: list[Path], mk: Path) -> str:
    images = "".join(f'[[images]]\nname = "im{i}"\nlabel = "{lab}"\npixels = "{pix}"\ngroup = "o{i % 2}"\n\n'
                     for i, (lab, pix) in enumerate(zip(labels, pixels)))
    return (f'[run]\noutput = "{folder / "run_out"}"\nname = "fuzz"\n\n[kernels]\nmetakernel = "{mk}"\n\n'
            f'{images}[rpc]\nenabled = true\nheight_range = [-300.0, 300.0]\n\n[tiepoints]\ncell = 48\n'
            'search = 128.0\n\n[adjust]\ndegree = 1\n')


# --- the targets ------------------------------------------------------------------------------------

def build_targets(folder: str | os.PathLike[str]) -> dict[str, Target]:
    """Write the seeds into ``folder`` and return every target by name (shared-set targets when present)."""
    from lunarmap.adjust.bal import write_bal
    from lunarmap.adjust.network import write_network
    from lunarmap.matching import write_tiepoints
    from lunarmap.orientation.drivers import image_support
    from lunarmap.rpc import write_netcdf, write_rpc_txt
    from lunarmap.spice import KernelSet
    from lunarmap.synthetic import write_mission

    folder = Path(folder)
    mission_mk = write_mission(folder / "mission")
    mission = mission_mk.parent
    mission_set = KernelSet.from_metakernel(mission_mk)
    shared = shared_kernels()
    sets = sorted(p for p in shared.iterdir() if p.is_dir()) if shared else []

    def seed(path: Path, **context) -> Seed:
        return Seed(path.read_bytes(), "".join(path.suffixes[-1:]), context, path.name)

    labels = sorted(mission.glob("*.lbl"))
    shared_labels = sorted(p for s in sets for p in s.glob("*.lbl"))
    targets: dict[str, Target] = {}
    targets["pvl_label"] = Target("pvl_label", call_pvl, [seed(p) for p in labels + shared_labels])

    # ISIS cube tables: a cube written here, and the LRO NAC cube when present
    t = np.linspace(0, 1, 7)
    cube = isis_cube_bytes({
        "InstrumentPointing": {"J2000Q0": np.cos(t), "J2000Q1": np.sin(t), "J2000Q2": np.zeros(7),
                               "J2000Q3": np.zeros(7), "AV1": np.zeros(7), "AV2": np.zeros(7), "AV3": np.zeros(7),
                               "ET": 3e8 + t},
        "InstrumentPosition": {"J2000X": 1e3 + t, "J2000Y": t, "J2000Z": t, "ET": 3e8 + t},
        "Counts": {"Index": np.arange(7, dtype="<i4"), "Value": np.ones(7, dtype="<f4")},
    })
    cubes = [Seed(cube, ".cub", {"tables": ["InstrumentPointing", "InstrumentPosition", "Counts"]}, "synthetic.cub")]
    cubes += [seed(p, tables=["InstrumentPointing", "InstrumentPosition", "BodyRotation", "SunPosition"])
              for s in sets for p in s.glob("*.cub")]
    targets["isis_table"] = Target("isis_table", call_isis_table, cubes, kind="cube")

    mks = []
    for mk in [mission_mk, *(p for s in sets for p in s.glob("*.tm"))]:
        mks.append(Seed(_absolute_metakernel(mk.read_text(), mk.parent).encode(), ".tm", {}, mk.name))
    targets["meta_kernel"] = Target("meta_kernel", call_meta_kernel, mks)

    rfm = _rfm_seed(folder)
    rpc_txt = write_rpc_txt(rfm, folder / "seed_RPC.TXT")
    (folder / "seed_geoeye_RPC.TXT").write_text(_geoeye_text(rfm))
    targets["rpc_txt"] = Target("rpc_txt", call_rpc_txt, [seed(rpc_txt), seed(folder / "seed_geoeye_RPC.TXT")])
    targets["rpc_netcdf"] = Target("rpc_netcdf", call_rpc_netcdf, [seed(write_netcdf(rfm, folder / "rpc.nc"))],
                                   kind="netcdf")

    bal = _bal_seed()
    write_bal(folder / "seed.bal", bal)
    meta = {"units": "pixels", "images": ["a", "b", "c", "d"], "control_points": [0, 3, 7], "truth": {"sigma": 0.5}}
    targets["bal"] = Target("bal", call_bal, [seed(folder / "seed.bal")])
    targets["bal_meta"] = Target("bal_meta", call_bal_meta,
                                 [Seed(json.dumps(meta).encode(), ".meta.json",
                                       {"bal": (folder / "seed.bal").read_bytes()}, "seed.meta.json")], kind="json")

    targets["network"] = Target("network", call_network, [seed(write_network(_network_seed(), folder / "net.nc"))],
                                kind="netcdf")
    targets["tiepoints"] = Target("tiepoints", call_tiepoints,
                                  [seed(write_tiepoints(_tiepoint_seed(), folder / "tie.nc"))], kind="netcdf")

    isds = []
    for lab in labels[:3] + labels[-1:]:
        # line-scan seeds cut to 4,000 lines (401 epochs, like ALE's NAC ISD): the full 52,224-line
        # image has 5,223 epochs and takes ~1 s per read, which would starve the fuzzing of inputs
        short = folder / lab.name
        short.write_text(re.sub(r"Lines\s*=\s*52224", "Lines   = 4000", lab.read_text()))
        out = folder / f"{lab.stem}.json"
        image_support(short, mission_set).write_json(out)
        isds.append(seed(out))
    if shared and (shared / "lro_nac_M103595705LE" / "ale_isd.json").is_file():
        isds.append(seed(shared / "lro_nac_M103595705LE" / "ale_isd.json"))
    targets["isd_json"] = Target("isd_json", call_isd_json, isds, kind="json")

    def label_target(name: str, pairs: list[tuple[Path, KernelSet]]) -> None:
        if pairs:
            targets[name] = Target(name, call_image_support, [seed(p, kernels=k) for p, k in pairs],
                                   prepare=prepare_kernels)

    label_target("image_support_synthetic", [(p, mission_set) for p in labels])
    for name, key in (("lro", "lro_nac"), ("kaguya", "kaguya_tc"), ("clementine", "clementine_uvvis")):
        pairs = [(p, KernelSet.from_metakernel(next(s.glob("*.tm")))) for s in sets if s.name.startswith(key)
                 for p in sorted(s.glob("*.lbl"))]
        label_target(f"image_support_{name}", pairs)
    label_target("image_support_other", [(p, KernelSet.from_metakernel(next(s.glob("*.tm")))) for s in sets
                                         if s.name.startswith(("apollo", "lunar_orbiter"))
                                         for p in sorted(s.glob("*.lbl"))])

    image_list = folder / "images.txt"
    image_list.write_text("# label meta-kernel\n" + "".join(f"{p} {mission_mk}\n" for p in labels)
                          + f"'{labels[0]}' \"{mission_mk}\"  # quoted\n")
    targets["image_list"] = Target("image_list", call_image_list, [seed(image_list)])

    # issue 28: pixels of ISIS cubes, PDS3 images and GeoTIFF
    from lunarmap.io import write_cube

    rng = np.random.default_rng(9)
    pix = rng.normal(100, 20, (2, 20, 24))
    pix[0, 2, 3] = np.nan
    cubes_px = [Seed(write_cube(folder / "px_tile.cub", pix, pixel_type="SignedWord", base=50.0, multiplier=0.5,
                                tile=(8, 8), label_bytes=4096).read_bytes(), ".cub", {}, "px_tile.cub"),
                Seed(write_cube(folder / "px_bsq.cub", pix[0], pixel_type="Real", fmt="BandSequential",
                                byte_order="Msb", label_bytes=4096).read_bytes(), ".cub", {}, "px_bsq.cub")]
    targets["isis_cube"] = Target("isis_cube", call_isis_cube, cubes_px, kind="cube")
    targets["pds3_image"] = Target("pds3_image", call_image, [Seed(_pds3_bytes(), ".img", {}, "image.img")])
    tifs = _geotiff_seeds(folder)
    if tifs:
        targets["geotiff"] = Target("geotiff", call_image, tifs, kind="binary")

    # ISIS control networks: binary versions 5 and 2, PVL
    from lunarmap.io.isis_network import write_isis_network
    from lunarmap.io.isis_network_pvl import write_pvl_network

    import isisnet_help

    isis_ds = isisnet_help.random_network(8, per_point=3, n_img=4, seed=2)
    targets["isis_network_v5"] = Target("isis_network_v5", call_isis_network,
                                        [seed(write_isis_network(isis_ds, folder / "n5.net"))], kind="cube")
    targets["isis_network_v2"] = Target("isis_network_v2", call_isis_network,
                                        [seed(write_isis_network(isis_ds, folder / "n2.net", version=2))], kind="cube")
    targets["isis_network_pvl"] = Target("isis_network_pvl", call_isis_network,
                                         [seed(write_pvl_network(isis_ds, folder / "n.pvl"))])

    # a camera from spiceinit tables: the LRO NAC cube (a 400-line stand-in of its image, as in test_cube_camera)
    if shared and (shared / "lro_nac_M103595705LE" / "M103595705LE.cub").is_file():
        targets["cube_camera_lro"] = Target("cube_camera_lro", call_cube_camera,
                                            [seed(shared / "lro_nac_M103595705LE" / "M103595705LE.cub",
                                                  image_size=(400, 5064))], kind="cube")

    # run configuration: absolute paths to files that exist
    px = [folder / "px_bsq.cub"] * 2
    cfg = folder / "run.toml"
    cfg.write_text(_run_config_text(folder, labels[:2], px, mission_mk))
    targets["run_config"] = Target("run_config", call_run_config, [seed(cfg)])
    return targets

