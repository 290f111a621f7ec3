"""`memslidar docs`: the numbers in README.md and docs/results.md, rendered from the results.json of finished runs.

A run's output folder (`memslidar reproduce` or `memslidar site train`) is stored once: its results.json goes to
docs/results/<kind>_<name>.json and its main figure to docs/figures/; from the stored files, every generated block
of README.md and docs/results.md is rendered again. A generated block sits between two marker lines

    <!-- BEGIN GENERATED name -->
    <!-- END GENERATED name -->

and nothing else in a page is touched. Each table carries its header: date, machine (CPU model and vector
extensions), commit and command (experiments.report.run_header), so prose never has to.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.experiments.report import (
    bin_table,
    cpu_table,
    final_test_lines,
    interval_note,
    order_statement,
    orientation_bin_table,
    run_header,
    table3,
    wall_time,
)
from pcdet_memslidar.experiments.site_report import side_by_side, sites_table
from pcdet_memslidar.utils.atomic import write_bytes, write_text

STORE = Path("docs") / "results"  # the stored results.json files, relative to the repository root
FIGURES = Path("docs") / "figures"
PAGES = (Path("README.md"), Path("docs") / "results.md")  # the pages whose generated blocks are rendered
BLOCK = re.compile(r"^<!-- BEGIN GENERATED (\S+) -->\n(.*?)^<!-- END GENERATED \1 -->$", re.DOTALL | re.MULTILINE)
MAIN_PROFILE = "quick"  # the reproduction README shows


def machine_key(results: dict) -> str:
    """The CPU and torch's vector code of a run, as one lower-case word for file names:
    'intel_r_xeon_r_processor_avx512'."""
    machine = results["environment"]["machine"]
    return "_".join(re.findall(r"[a-z0-9]+", f"{machine['cpu']} {machine.get('aten_cpu_capability') or ''}".lower()))


def run_kind(results: dict) -> tuple[str, str]:
    """('reproduce', '<profile>_<machine_key>') or ('site', site name) of a results dict: a reproduction is stored
    once per CPU and vector code, a site once."""
    if "models" in results and "test_domain" in results:
        return "reproduce", f"{results['profile']}_{machine_key(results)}"
    if "site" in results and "scores" in results:
        return "site", results["site"]
    raise ConfigError("not the results of `memslidar reproduce` or `memslidar site train` (no models or scores)")


def store_run(run_dir: Path, root: Path) -> Path:
    """Copy run_dir/results.json to root/STORE/<kind>_<name>.json and the run's main figure (Table 3's intervals, or
    the site's held-out frames) to root/FIGURES; returns the stored file."""
    source = run_dir / "results.json"
    if not source.is_file():
        raise DataFormatError(run_dir, "no results.json here: give the output folder of a finished `memslidar "
                                       "reproduce` or `memslidar site train`")
    try:
        results = json.loads(source.read_text())
        kind, name = run_kind(results)
    except (json.JSONDecodeError, ConfigError) as error:
        raise DataFormatError(source, f"{error}; give the output folder of a finished run") from None
    target = root / STORE / f"{kind}_{name}.json"
    write_text(target, json.dumps(results, indent=1) + "\n")
    figure = (run_dir / results.get("figures", {}).get("ap_intervals", "") if kind == "reproduce"
              else Path(results.get("figure", "")))
    if figure.is_file():
        name_of = f"table3_{name}_ap_intervals.png" if kind == "reproduce" else f"site_{name}_detections.png"
        (root / FIGURES).mkdir(parents=True, exist_ok=True)
        write_bytes(root / FIGURES / name_of, figure.read_bytes())
    return target


def stored_runs(root: Path) -> dict[str, dict]:
    """{file stem: results} of every stored run under root/STORE, in name order."""
    return {path.stem: json.loads(path.read_text()) for path in sorted((root / STORE).glob("*.json"))}


def reproduce_block(results: dict, details: bool = False) -> list[str]:
    """Table 3 of a stored reproduction with its header and the paper's order; with `details` (docs/results.md) also
    the intervals' meaning, Table 3 on the untouched seed and the distance-bin tables."""
    lines = [f"Source: {run_header(results)}; {wall_time(results)}.", "", *table3(results), "",
             order_statement(results), ""]
    if not details:
        return lines + ["The same checkpoints on an untouched seed of the test domain, and AP per distance: "
                        "[docs/results.md](docs/results.md)."]
    note, orientation = interval_note(results), orientation_bin_table(results)
    lines += [*([note, ""] if note else []), *final_test_lines(results),
              "AP 3D R40 per distance bin (BEV range from the sensor):", "", *bin_table(results), ""]
    if orientation:
        lines += ["Median orientation error (deg) per distance bin, against the simulator's labels:", "",
                  *orientation, ""]
    return lines


def blocks(runs: dict[str, dict]) -> dict[str, list[str]]:
    """{block name: its lines} from the stored runs: `table3` (the newest quick reproduction), `cpus` (every quick
    reproduction, one row per CPU and vector code), `sites` (every site side by side), `results` (docs/results.md's
    body: each profile's newest reproduction with its details, every site's full table)."""
    reproductions = {name: results for name, results in runs.items() if name.startswith("reproduce_")}
    sites = [results for name, results in runs.items() if name.startswith("site_")]
    quick = sorted((item for item in reproductions.items() if item[1]["profile"] == MAIN_PROFILE),
                   key=lambda item: item[1]["date"])
    missing = ["No stored run yet: `memslidar docs --add OUTPUT_FOLDER` stores one."]
    body = []
    newest = {}  # per profile its newest reproduction, in full; the others are rows of the CPU table
    for results in sorted(reproductions.values(), key=lambda results: results["date"]):
        newest[results["profile"]] = results
    for results in newest.values():
        machine = results["environment"]["machine"]
        body += [f"## Table 3: {results['profile']} profile, {len(results['seeds'])} seed(s), {machine['cpu']} "
                 f"(torch vector code {machine.get('aten_cpu_capability') or 'n/a'})", "",
                 *reproduce_block(results, details=True)]
    if sites:
        body += ["## Sites: detectors from an empty recording", "", *sites_table(sites), ""]
        for results in sites:
            body += [f"### {results['site']}", "", f"Source: {run_header(results)}.", "", *side_by_side(results), ""]
    table3 = missing
    if quick:
        name, main = quick[-1]
        figure = FIGURES / f"table3_{name.removeprefix('reproduce_')}_ap_intervals.png"
        table3 = [*reproduce_block(main), "", f"![AP of every model with its 95 % interval beside the paper's]"
                                              f"({figure.as_posix()})"]
    return {"table3": table3, "cpus": cpu_table([results for _, results in quick]) if quick else missing,
            "sites": sites_table(sites) if sites else missing, "results": body or missing}


def fill_blocks(text: str, rendered: dict[str, list[str]], page: Path) -> str:
    """`text` with every generated block's body replaced by rendered[name]; DataFormatError naming the page for a
    block name nothing renders."""
    def body(match: re.Match) -> str:
        name = match.group(1)
        if name not in rendered:
            raise DataFormatError(page, f"unknown generated block '{name}': use one of {', '.join(rendered)}")
        content = "\n".join(rendered[name]).strip("\n")
        return f"<!-- BEGIN GENERATED {name} -->\n{content}\n<!-- END GENERATED {name} -->"
    return BLOCK.sub(body, text)


def strip_blocks(text: str) -> str:
    """`text` without its generated blocks (the prose a person wrote)."""
    return BLOCK.sub("", text)


def publish(root: Path, add: list[Path]) -> list[Path]:
    """Store the runs `add` under root, then render every generated block of root's PAGES; returns the pages
    written (only those whose text changed)."""
    for run_dir in add:
        store_run(run_dir, root)
    rendered, written = blocks(stored_runs(root)), []
    for page in PAGES:
        path = root / page
        if not path.is_file():
            raise DataFormatError(path, "missing: run `memslidar docs` from the repository root (--root)")
        text = path.read_text()
        new = fill_blocks(text, rendered, path)
        if new != text:
            write_text(path, new)
            written.append(path)
    return written
