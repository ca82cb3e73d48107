"""Rule fleet_index: every machine's files -> reports/index.html (rafi.report.fleet_page)."""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from pathlib import Path

    from rafi.ops.fleet import fleet_overview
    from rafi.ops.project import Paths
    from rafi.report.fleet_page import write_fleet_page

    smk = snakemake  # noqa: F821
    p = smk.params
    paths = Paths(Path.cwd(), Path(p.raw_dir).resolve(), Path(p.results_dir).resolve())
    rows = lambda: fleet_overview(paths, p.reports_dir, list(p.machines))  # noqa: E731 - read under the page lock
    out = write_fleet_page(paths, p.reports_dir, smk.output.html, rows=rows)
    print(f"wrote {out} ({len(p.machines)} machine(s))", flush=True)
