"""``sysid export`` and ``sysid validate``: identified models out as FMUs, and their checks."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError, SysidError


def _models(tree) -> dict[str, xr.Dataset]:
    if "models" not in tree or not tree["models"].children:
        raise InputDataError("the campaign has no identified models (/models/<name>); run "
                             "'sysid identify' first")
    return {name: node.to_dataset(inherit=False) for name, node in tree["models"].children.items()}


def _cmd_export(args: argparse.Namespace) -> int:
    from sysid.fmi.export import export_fmu
    from sysid.data.netcdf import read_campaign

    models = _models(read_campaign(args.campaign))
    if args.model not in models:
        raise InputDataError(f"model {args.model!r} is not in {args.campaign} (has "
                             f"{sorted(models)})")
    out = args.output or f"{args.model}.fmu"
    path = export_fmu(models[args.model], out, fmi_version=args.fmi,
                      model_name=args.name or f"sysid_{args.model}", step_size=args.step,
                      me_delay=args.me_delay, pade_order=args.pade_order, quiet=args.quiet)
    print(path)
    return 0


def _truth(tree, quiet: bool):
    """(truth FMU path, trim) or (None, reason)."""
    from sysid.truth import build_fmu, trim

    airspeed = 0.0
    if "trim" in tree:
        airspeed = float(tree["trim"].to_dataset().attrs.get("airspeed_kt", 0.0))
    try:
        path = build_fmu()
        return path, trim(airspeed, fmu=path)
    except SysidError as exc:
        return None, f"truth FMU not available ({exc})"


def validate_model(name: str, model: xr.Dataset, *, fmu_dir: Path, truth=None, trim=None,
                   frequency_response: xr.Dataset | None = None, envelopes=None,
                   quiet: bool = True) -> xr.Dataset:
    """Export one model and run the checks (a), (b) when ``truth`` is given, (c) when
    ``frequency_response`` is given; one Dataset for ``/validation/<name>``."""
    from sysid.fmi.export import export_fmu
    from sysid.assess.exported import (compare_with_truth, envelope_check, roundtrip_error,
                                      verification_inputs)

    path = export_fmu(model, fmu_dir / f"{name}.fmu", model_name=f"sysid_{name}", quiet=quiet)
    manoeuvres = verification_inputs()
    names = list(manoeuvres)
    ds = xr.Dataset(coords={"maneuver": names})
    ds["roundtrip_cs"] = ("maneuver", [roundtrip_error(model, path, manoeuvres[m], mode="cs")
                                       .attrs["max_relative_error"] for m in names],
                          {"long_name": "co-simulation vs sysid.models.simulate, "
                                        "max error / peak response"})
    ds["roundtrip_me"] = ("maneuver", [roundtrip_error(model, path, manoeuvres[m], mode="me")
                                       .attrs["max_relative_error"] for m in names],
                          {"long_name": "model exchange (CVode, delays from the input "
                                        "history) vs sysid.models.simulate, max error / "
                                        "peak response"})
    if truth is not None:
        runs = [compare_with_truth(path, truth, manoeuvres[m], trim=trim, model_name=name)
                for m in names]
        ds["j_rms"] = ("maneuver", [float(r["j_rms"].sel(source=name)) for r in runs],
                       {"long_name": "J_rms against the truth FMU"})
        ds["tic"] = (("maneuver", "channel"),
                     np.stack([r["tic"].sel(source=name).values for r in runs]),
                     {"long_name": "Theil inequality coefficient against the truth FMU"})
        ds = ds.assign_coords(channel=runs[0]["channel"].values)
    if frequency_response is not None:
        env = envelope_check(model, frequency_response, envelopes)
        for var in env.data_vars:
            ds[var if var not in ("magnitude", "phase") else f"mismatch_{var}"] = env[var]
    ds.attrs.update({"fmu": path.name, "model": name})
    return ds


def _cmd_validate(args: argparse.Namespace) -> int:
    from sysid.data.netcdf import read_campaign, update_campaign
    from sysid.assess.envelopes import MUAD

    tree = read_campaign(args.campaign)
    models = _models(tree)
    truth, trim = (None, "skipped (--no-truth)") if args.no_truth else _truth(tree, args.quiet)
    if truth is None:
        print(f"time-domain comparison with the truth FMU: {trim}")
        trim = None
    fr = tree["frequency_response"].to_dataset() if "frequency_response" in tree else None
    if fr is None:
        print("no /frequency_response in the campaign: envelope check skipped")
    envelopes = [MUAD, *args.envelope]
    rows = []
    with tempfile.TemporaryDirectory(prefix="sysid-validate-") as tmp:
        fmu_dir = Path(args.fmu_dir) if args.fmu_dir else Path(tmp)
        for name, model in models.items():
            try:
                ds = validate_model(name, model, fmu_dir=fmu_dir, truth=truth, trim=trim,
                                    frequency_response=fr, envelopes=envelopes,
                                    quiet=args.quiet)
            except Exception as exc:  # noqa: BLE001 - one model's failure is a result
                # A model can be unusable (e.g. a diverged fit whose FMU CVode cannot
                # integrate); that is a validation outcome to report and store, and the
                # other models are still validated.
                ds = xr.Dataset(attrs={"model": name,
                                       "error": f"{type(exc).__name__}: {exc}"})
                print(f"{name}: validation FAILED: {ds.attrs['error']}")
            update_campaign(args.campaign, f"validation/{name}", ds)
            rows.append((name, ds))
    failed = [name for name, ds in rows if "error" in ds.attrs]
    rows = [(name, ds) for name, ds in rows if "error" not in ds.attrs]
    if not rows:
        print(f"no model could be validated ({', '.join(failed)})")
        return 1
    header = f"{'model':<20}{'CS err':>10}{'ME err':>10}{'J_rms':>8}{'TIC max':>9}"
    env_names = [] if fr is None else [str(e) for e in rows[0][1]["envelope"].values]
    header += "".join(f"{e[:12] + ' in':>16}" for e in env_names)
    print(header)
    for name, ds in rows:
        line = (f"{name:<20}{float(ds.roundtrip_cs.max()):>10.1e}"
                f"{float(ds.roundtrip_me.max()):>10.1e}")
        line += (f"{float(ds.j_rms.mean()):>8.3f}{float(ds.tic.max()):>9.3f}" if "j_rms" in ds
                 else f"{'-':>8}{'-':>9}")
        for e in env_names:
            frac = float(ds.fraction_inside.sel(envelope=e).mean())
            line += f"{100 * frac:>15.0f}%"
        print(line)
    print("(errors: max deviation / peak response vs sysid.models.simulate; J_rms mean and TIC "
          "max over the verification 3211/2311 inputs; envelope: mean fraction of the coherent "
          f"band inside the bounds). Results stored under /validation/<model> in "
          f"{args.campaign}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help="export an identified model of a campaign as an FMU",
        description="Write a campaign model (/models/<name>) as one FMI 2.0 FMU (model "
                    "exchange and co-simulation, C sources included), in the truth FMU's "
                    "absolute units.")
    p.add_argument("campaign", help="campaign netCDF file")
    p.add_argument("--model", required=True, help="model group name, e.g. frequency_domain")
    p.add_argument("-o", "--output", help="FMU file to write (default <model>.fmu)")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (3: not "
                   "available yet)")
    p.add_argument("--name", help="model name in the FMU (default sysid_<model>)")
    p.add_argument("--step", type=float, default=0.01, help="default communication step, s")
    p.add_argument("--me-delay", choices=("buffer", "pade"), default="buffer",
                   help="delays in model exchange: input history held between input updates "
                        "(exact, default) or Pade approximants (see fmus/linear/README.md)")
    p.add_argument("--pade-order", type=int, default=6,
                   help="order of the Pade delays with --me-delay pade (default 6)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_cmd_export)

    v = subparsers.add_parser(
        "validate", help="export every campaign model and validate it",
        description="For every /models/* model: export it as an FMU, compare the FMU with "
                    "sysid.models.simulate (co-simulation and model exchange), with the truth "
                    "FMU from trim (3211/2311 inputs, J_rms and TIC) and check its mismatch "
                    "against /frequency_response with MUAD and user envelopes. Results go to "
                    "/validation/<model>.")
    v.add_argument("campaign", help="campaign netCDF file")
    v.add_argument("--envelope", action="append", default=[],
                   help="user envelope TOML file (e.g. AEE); may be repeated")
    v.add_argument("--fmu-dir", help="keep the exported FMUs in this folder")
    v.add_argument("--no-truth", action="store_true",
                   help="skip the time-domain comparison with the truth FMU")
    v.add_argument("--quiet", action="store_true", help="no progress lines")
    v.set_defaults(func=_cmd_validate)
