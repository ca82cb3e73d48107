"""Rule fleet_index: every machine's files -> reports/index.html (rafi.report.fleet_page)."""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from pathlib import Path

    from rafi.ops.fleet import fleet_overview
    from rafi.ops.project import Paths
    from rafi.report.fleet_page import write_fleet_page
    from rafi.settings import split_unit

    smk = snakemake  # noqa: F821
    p = smk.params
    paths = Paths(Path.cwd(), Path(p.raw_dir).resolve(), Path(p.results_dir).resolve())
    rows = lambda: fleet_overview(paths, p.reports_dir, list(p.machines))  # noqa: E731 - read under the page lock
    out = write_fleet_page(paths, p.reports_dir, smk.output.html, rows=rows)
    n = len({split_unit(unit)[0] for unit in p.machines})  # a machine with several probes is one
    print(f"wrote {out} ({n} machine(s), {len(p.machines)} qualification unit(s))", flush=True)
