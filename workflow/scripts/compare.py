"""Rule compare: runs + key sensors + model.json -> comparison/summary.csv, per_run.csv,
residuals.parquet, best_model.json, cv.csv, verdict.csv, since_change.csv (docs/models.md).

verdict.csv stores every model's gates per validation run (the rows of
rafi.method.validate.qualify, named by model and model id): the report reads them there.

best_model.json is the model chosen by whole-run CV on the training runs (the champion),
whether or not it passes the gates on the validation runs: no second pick.

The CV rows are memoised by content in ``results/<machine>/.cv_memo/`` (not an output:
:mod:`rafi.family.cv_memo`, keyed by the training logs, the settings and ``params.code``).

``params.prior`` (``models.prior``, resolved while planning) names the registry's candidate
priors; the job chooses the first that learnt from none of these runs, checks it
(:func:`rafi.family.prior.resolved_prior`: a prior of another machine not declared a sibling stops
the job with one line) and the adaptation candidates join the family, each with its fitness block
(the prior's origin and qualification: :func:`rafi.family.prior.prior_record`).

A warning line names the training runs no model explains (:mod:`rafi.family.unexplained`), and
one the runs set aside before a change (``models.since_change``, :mod:`rafi.family.since_change`);
the end-of-run lines repeat them under the machine's line."""

import json

from _glue import as_table, read_runs, step, warn

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.family.compare import load_any, run_family
    from rafi.family.prior import prior_record, resolved_prior
    from rafi.family.since_change import change_text
    from rafi.family.unexplained import unexplained_text

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
    prior = resolved_prior(
        smk.params.prior,
        table,
        frame,
        unit=smk.params.machine,
        log=lambda m: print(m, flush=True),
    )
    with open(smk.input.key_sensors, encoding="utf-8") as fh:
        key_sensors = json.load(fh)["sensors"]
    result = run_family(
        table,
        frame,
        key_sensors=key_sensors,
        terms=smk.params.fit["terms"],
        reference=smk.params.reference,
        machine=smk.params.machine,
        options=smk.params.models,
        gates=smk.params.gates,
        hac_maxlags=smk.params.fit["hac_maxlags"],
        speed_tolerance_rpm=smk.params.speed_tolerance_rpm,
        rafi_model=load_any(smk.input.model),
        cv_memo_dir=smk.params.cv_memo,
        code_version=smk.params.code,
        log=lambda m: print(m, flush=True),
        prior=prior,
        prior_origin=prior_record(smk.params.prior, prior),
    )
    cols = ["model", "cv_mean_max_abs_um", "cv_forward_mean_max_abs_um", "selection_score_um"]
    cols += ["selection_rank", "max_abs_after_um", "passed", "champion", "candidate", "versus_plain_ridge"]
    print(result["summary"][cols].to_string(index=False), flush=True)
    print(
        f"champion {result['champion']} (chosen by {result['selection_basis']} on the training runs) "
        f"{'passes' if result['champion_passed'] else 'FAILS'} the gates on the validation runs",
        flush=True,
    )
    if not result["champion_passed"]:
        print(
            f"WARNING: the chosen model {result['champion']} fails the gates; best_model.json is "
            "still that model (no second pick on validation) and the registry will not promote it",
            flush=True,
        )
    for warning in (change_text(result["since_change"]), unexplained_text(result["cv"])):
        if warning:
            warn(smk, "compare", warning)
    rafi.artefact.write_csv_atomic(as_table(result["summary"]), smk.output.summary, index=False)
    rafi.artefact.write_csv_atomic(as_table(result["per_run"]), smk.output.per_run, index=False)
    rafi.artefact.write_csv_atomic(as_table(result["verdict"]), smk.output.verdict, index=False)
    rafi.artefact.write_parquet_atomic(result["residuals"], smk.output.residuals)
    rafi.artefact.write_csv_atomic(as_table(result["cv"]), smk.output.cv, index=False)
    rafi.artefact.write_csv_atomic(as_table(result["since_change"]), smk.output.since_change, index=False)
    rafi.artefact.write_text_atomic(smk.output.best_model, rafi.artefact.json_text(result["best_artefact"]))
