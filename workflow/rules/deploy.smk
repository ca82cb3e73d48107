# The model on the machine, offline: the replay of recorded runs through the safe compensator
# (rafi.deploy.replay; docs/deploy.md, section Replay).
#
#   candidate model (nightly.candidate: comparison/best_model.json by default, the model this
#   run offers to the machine) + runs.csv + runs.parquet  ->  deploy/replay.parquet (one row
#   per sample of each replayed run) and deploy/replay_summary.csv (one row per run)
#
# The runs replayed are those whose role is in deploy.replay_roles; the limits in force are the
# machine's deploy: settings (replay_settings() in common.smk: the limits and replay_roles only,
# so a change of the controller's connection settings re-runs nothing). Uses the helpers of
# common.smk (candidate_model, out, log_path, bench_path, code_version, replay_settings).


rule replay:
    """Feed the replayed runs' logs sample by sample through the compensator with the limits."""
    input:
        model=candidate_model,
        table=out("runs_csv"),
        frame=out("runs_parquet"),
    output:
        table=out("replay"),
        summary=report(
            out("replay_summary"),
            caption="../report/replay_summary.rst",
            category="Replay",
            subcategory="{machine}",
            labels={"machine": "{machine}", "table": "deploy/replay_summary.csv"},
        ),
    log:
        log_path("replay"),
    benchmark:
        bench_path("replay")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("replay"),
        deploy=lambda w: replay_settings(w.machine),
    script:
        "../scripts/replay.py"
