"""Re-qualification in hours: validation MAE and worst residual against hours of new data (issues 27, 47).

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_requalify.py                               # every scenario, 1 2 4 8 h
    python benchmarks/bench_requalify.py --scenario season --hours 2 4
    python benchmarks/bench_requalify.py --machine machining-center-b --sample-period 30
    python benchmarks/bench_requalify.py --random 40 --keep benchmarks/results/requalify_random
    python benchmarks/bench_requalify.py --seeds 40-59 --keep benchmarks/results/requalify_random
    python benchmarks/bench_requalify.py --seeds 36-47 --no-fold-hours 2 --keep DIR   # the no-fold default
    python benchmarks/bench_requalify.py --issue-scenarios --seeds 9001-9002          # issue 47's two
    python benchmarks/bench_requalify.py --false-siblings --seeds 0-23                 # a foreign prior
    python benchmarks/bench_requalify.py --other-designs --seeds 0-39                  # random designs

**Named scenarios.** For each twin scenario (:mod:`rafi.twin.scenarios`: ``sibling``, ``reworn``,
``season``, ``replaced_sensor``), the OLD machine's full qualification is fitted with rule
compare's :func:`rafi.family.compare.run_family` (every enabled kind, whole-run CV, the champion
chosen by CV); its champion's artefact is the PRIOR. On the NEW machine, for each budget of
hours the programme ``rafi plan --hours`` writes with that prior (:func:`plan_for`: the plan
shaped by the prior, :func:`rafi.ops.plan.plan_programme`) is simulated as one log (every
heat-up and cool-down a training run), and the validation MAE (mean |measured - predicted| over
every sample of the new machine's validation runs) and worst residual (max |measured -
predicted| over them: five single-speed runs and the multi-condition run, um) are printed for:

* ``scratch``: run_family on those hours alone, no prior (the champion CV chose);
* ``prior``: run_family on those hours with ``prior=`` the old champion (the adaptation
  candidates beside the from-scratch kinds, all chosen by the same CV; needs run_family's
  ``prior`` argument, else shown as ``-``);

and beside them, per scenario: ``full``: run_family from scratch on the new machine's full
test plan (six 4 h runs, 24.3 h); ``unchanged``: the prior on the new validation runs as it
is; ``floor``: the noise floor (max |measured - true displacement rise| over the validation
runs: what a perfect model would still show). Nothing is chosen on validation runs: every
choice is the CV on the training runs; the validation runs are only scored.

**Random scenarios** (``--random N``: seeds 0..N-1; ``--seeds A-B``): each seed is a scenario of
:func:`rafi.twin.requalify_scenarios.random_scenario` (a base machine, a repair, a sibling, a
season or a moved sensor, its size drawn from the seed). The prior is the base machine's
champion on its full plan (the named scenarios' old machine at ``--seed``); the new machine gets
:data:`TARGET_HOURS` of new data (the plan with the prior), and the table gives, on the same
validation runs of the changed machine, MAE ; worst of: the full plan from scratch, 4 h with
the prior (the CV's pick), 4 h from scratch (the CV's pick among the from-scratch candidates of
the same fit: each candidate's CV does not depend on the others) and the prior unchanged;
whether "4 h with the prior within 15 % of the full plan from scratch on both MAE and worst"
holds, and the share of scenarios where it does (issue 47's target: at least 80 % of at least
20 scenarios), then the counts by base machine and kind of change beside the prior unchanged,
from scratch and the best candidate in hindsight (:func:`by_change_markdown`: the ceiling of a
choice among the candidates), and the same four counts at looser tolerances than 15 %
(:func:`tolerance_markdown`: what the target asks). With ``--keep DIR`` each seed's result is
``DIR/seed-<n>.json`` (every candidate's CV scores and validation MAE and worst), read back instead
of run again. With ``--repeat-full`` each scenario's full plan is also run a second time on the
same machine (:func:`repeat_full`: fresh noise and weather, the same validation runs) and counted
beside the four: how close the reference comes to itself. Measured 2026-11-30 (``--seeds 0-239
--keep DIR --repeat-full``): within 15 % of itself on both in 165 of 240 (69 %); on seeds
240-279 24 of 40.

**The choice among adaptations** (issue 47, item 4), judged one level up on the random
scenarios, from the kept per-candidate numbers (no refit): the rules of :data:`RULES` -

* ``cv``: the product's rule until 2026-11-29 (the lowest mean held-out max |residual| of the
  whole-run CV, among every candidate, adaptations and kinds; with an ensemble prior the product
  now follows ``shared_gain_unless_beaten``, below);
* ``one_se_simplest``: the simplest candidate (``prior`` < ``prior_gain`` < ``prior_time`` <
  ``prior_ridge`` < the from-scratch kinds by simplicity) whose CV score is within one standard
  error (of the best candidate's held-out max |residual|s) of the best;
* ``mean_and_worst``: the lowest mean of the CV's pooled RMSE and its mean held-out max |residual|;
* ``adaptations_only``: with a prior, the CV's rule among the adaptation candidates only.

The criterion, written down before any random scenario was run (2026-11-29): a rule's score is
its **share of scenarios whose pick is within 15 % of the full plan from scratch on both the
validation MAE and the worst residual**; between equal shares, the lower **mean ratio** (over
scenarios, of the mean of the two ratios pick / full plan) wins. The product's rule (``cv``)
stays unless another rule beats it by this criterion (a strictly higher share, or the same
share and a lower mean ratio); only then is the winner put in the product.

Measured 2026-11-29 (``requalify_random.md``). On seeds 0-39: ``cv`` 35 % (mean ratio
1.374), ``one_se_simplest`` 32 % (1.694), ``mean_and_worst`` 35 % (1.317), ``adaptations_only``
35 % (1.340): ``mean_and_worst`` by the tie-break. On seeds 0-49: ``cv`` 36 % (1.462),
``one_se_simplest`` 36 % (1.711), ``mean_and_worst`` 36 % (1.417), ``adaptations_only`` 38 %
(1.441): ``adaptations_only`` by one scenario. The winner changes with ten more scenarios and
every margin is one scenario or a tie-break, so no rule is put in the product: the product's
``cv`` stays. Even the pick made with hindsight on the validation runs is within 15 % on both
in 22 of 50: no choice among these candidates reaches the 80 % target at 4 h.

**One shared adaptation over the whole ensemble prior** (issue 47; criterion written 2026-11-29
before any scenario was scored with them). Two candidates beside today's, offered only when the
prior is a CV-weighted ensemble (:data:`rafi.family.adapted.ENSEMBLE_CANDIDATES`): every member
keeps its coefficients and the prior's weights, and

* ``prior_shared_gain``: the blended prediction times one gain ``g`` (least squares through the
  reference on the new training runs, as ``prior_gain`` for one member);
* ``prior_shared_time``: every member's filter time constants times one factor (``prior_time``'s
  grid and whole-run CV) and the blend times one gain.

Each is judged by what it would put in the product: the product's CV rule choosing among today's
candidates plus ``prior_shared_gain`` (candidate A), plus both (candidate B), against the same
rule among today's candidates only ("today"), all from the same run (each candidate's CV does not
depend on the others). Developed on seeds 0-11, confirmed on seeds 12-23. A candidate is adopted
only if, **on seeds 12-23**, (1) its share of scenarios within 15 % of the full plan from scratch
on both the validation MAE and the worst residual is **strictly higher** than today's, and (2)
the mean over those scenarios of the MAE ratio (4 h with the prior / full plan) is not higher than
today's by more than **one standard error** (the standard error of the mean of the per-scenario
differences, candidate minus today; ``judge_shared``). Between A and B, both adopted: the higher
share on 12-23, then the lower mean MAE ratio, then A (the simpler). Otherwise neither enters
the product. Seeds 0-11 are only for developing; nothing is changed after the confirmation seeds
are scored.
Development, seeds 0-11 (2026-11-29, ``--seeds 0-11 --keep``, nothing changed after it): today 4 of
12 within 15 % on both (mean MAE ratio 1.595); A 7 of 12 (1.305; difference -0.290, SE 0.139); B
the same picks as A (the CV never took ``prior_shared_time``).
Confirmation, seeds 12-23 (``--seeds 12-23 --keep``, the same code): today 4 of 12 within 15 % on
both (on MAE 4, on worst 7; mean MAE ratio 1.798); A 5 of 12 (on MAE 5, on worst 9; 1.487,
difference -0.311, SE 0.214); B the same picks as A again. The criterion holds for A and for B;
between them the tie goes to A. **``prior_shared_gain`` is offered** (the CV took it in 21 of
24 scenarios); ``prior_shared_time`` is not (its code: the branch of issue 47 before it was
taken out). Over all 24: today 8, A 12 (50 %): better, by one scenario on the confirmation
seeds, and far from the 80 % target; with hindsight a candidate within 15 % on both exists in 11
of 24 today, 14 with the shared ones.

**The members re-weighted** (issue 47; criterion written 2026-11-29 before any scenario was
scored with it). One candidate beside today's (today's = every candidate the product offers,
``prior_shared_gain`` included), offered only for a CV-weighted ensemble prior:

* ``prior_member_weights``: every member keeps its coefficients, the members' weights are
  re-fitted on the new training runs: non-negative least squares (no intercept) of the measured
  displacement change on the members' predictions, shrunk towards the prior's weights times the
  shared gain ``g`` (a ridge on the weights towards ``g w_prior``, its strength chosen by whole-run
  CV on the new training runs on a small grid that includes infinity, i.e. ``prior_shared_gain``
  itself; no fold: the shared gain). After a repair that moves the time constants, members of
  other lags can be re-weighted to follow.

It is judged by what it would put in the product: the product's CV rule choosing among today's
candidates plus ``prior_member_weights`` (candidate C) against the same rule among today's only
(``judge_member_weights``), from the same run. It is adopted only if **both** on the development
seeds 0-11 **and** on the confirmation seeds 24-35 (new, never run before this criterion was
written), (1) its share of scenarios within 15 % of the full plan from scratch on both the
validation MAE and the worst residual is **strictly higher** than today's, and (2) the mean over
those scenarios of the MAE ratio (4 h with the prior / full plan) is not higher than today's by
more than **one standard error** of the per-scenario differences (candidate minus today).
Otherwise it does not enter the product (its code: the tag ``study/issue47-member-weights``).
Nothing is changed after the confirmation seeds are scored.
Development, seeds 0-11 (2026-11-29, ``--seeds 0-11 --keep``): today 7 of 12 within 15 % on both
(on MAE 7, on worst 9; mean MAE ratio 1.305); C 7 of 12 (on MAE 7, on worst 9; 1.313, difference
+0.009, SE 0.031): the CV took ``prior_member_weights`` in 4 (seeds 1, 5, 7, 8), none of which
changed side. Confirmation, seeds 24-35 (``--seeds 24-35 --keep``, the same code): today 3 of 12
(on MAE 7, on worst 4; 1.613); C 4 of 12 (on MAE 7, on worst 5; 1.621, difference +0.008, SE
0.008): seed 28 (a repair) passes with it. The share is not strictly higher on the development
seeds: **``prior_member_weights`` is not offered** (its code, its tests and
``judge_member_weights``: the tag ``study/issue47-member-weights``). With hindsight it is within
15 % on both in 7 of 12 and 5 of 12, where some other candidate is in 8 and 5 (it alone: seed 28): the
members of an ensemble prior are near-collinear on a few hours of new data (the CV chose the
infinite strength, the shared gain itself, in 9 of 24), and on the repairs (1, 3, 7, 30, 33, 35) no
weighting of the prior's lags reaches the faster time constants. Seeds 24-35 are harder for today's
product too: 3 of 12 (seeds 0-11: 7, 12-23: 5; 15 of 36 in all).

**The no-fold default with an ensemble prior** (issue 47; criterion written 2026-11-29 before
seeds 36-47 were run). A programme too short for a CV fold (one training run: the 2 h plan)
gets :func:`rafi.family.selection.default_champion`: ``prior_gain``, the heaviest member of an
ensemble prior with one gain. The change judged: ``prior_shared_gain`` (the whole ensemble prior
times one gain) as that default when the prior is an ensemble (a prior of one kind keeps
``prior_gain``). Judged with ``--no-fold-hours 2`` (``judge_no_fold``): on each random scenario,
the plan with the prior for 2 h of new data, the two candidates' validation MAE and worst residual
over the full plan from scratch's (the same validation runs). It is adopted only if, **on seeds
36-47** (new, never run before this criterion was written), (1) the share of scenarios within
15 % of the full plan from scratch on both the validation MAE and the worst residual with
``prior_shared_gain`` is **not lower** than with ``prior_gain``, and (2) the mean over those
scenarios of the MAE ratio (2 h / full plan) is **lower by more than one standard error** of the
per-scenario differences (``prior_shared_gain`` minus ``prior_gain``: mean difference < -SE).
Only scenarios whose 2 h fit has no fold count (a 2 h plan that gives a fold is said and left
out). Development evidence only, not a confirmation (measured before this criterion was
written, by a script outside the bench reusing its functions): on the 2 h plan, within 15 % on
both, seeds 0-11 ``prior_gain`` 2 of 12, ``prior_shared_gain`` 7 (mean MAE ratio 1.549 -> 1.263,
difference -0.286, SE 0.074); seeds 24-35 2 -> 3 (1.417 -> 1.363, -0.054, SE 0.040). Nothing is
changed after seeds 36-47 are scored.
Confirmation, seeds 36-47 (2026-11-29, ``--seeds 36-47 --no-fold-hours 2 --keep``; every 2 h
plan one training run, no fold, the prior an ensemble, the product's pick ``prior_gain`` in all
12): ``prior_gain`` within 15 % on both in 5 of 12 (on MAE 5, on worst 8; mean MAE ratio 1.445);
``prior_shared_gain`` 7 of 12 (on MAE 7, on worst 12; 1.257, difference -0.188, SE 0.085):
seeds 38 (a moved sensor) and 43 (a repair) pass with it, none fails with it that passes with
``prior_gain``. The criterion holds: **with an ensemble prior and no fold the default is
``prior_shared_gain``** (:func:`rafi.family.selection.default_champion`; a prior of one kind
keeps ``prior_gain``). The same seeds at 4 h with the prior (the CV's pick): 5 of 12.

**The shared gain unless beaten** (issue 47; criterion written 2026-11-29 before seeds 48-59 were
run and before either rule below was scored on any seed). With three training runs the CV's
choice among close candidates is noise (three folds); the shared gain is one parameter. Two
rules of :data:`RULES`, judged against ``cv`` (the product's rule) from the kept per-candidate
numbers, every rule choosing among the candidates the product offers today (a kept record's
``prior_shared_time`` or ``prior_member_weights`` is dropped first):

* ``shared_gain_unless_beaten``: with an ensemble prior (``prior_shared_gain`` among the
  candidates), ``prior_shared_gain`` unless some candidate's CV score (``selection_score_um``)
  is lower than its by more than one standard error of the **paired per-fold differences** (that
  candidate's held-out max |residual| minus the shared gain's, fold by fold over the same
  whole-run folds: ``cv_fold_max_abs_um``, kept for every candidate; SE = their sample standard
  deviation / sqrt(number of folds)); then the lowest CV score among the candidates that beat it
  so. Without an ensemble prior: ``cv``.
* ``always_shared_gain``: ``prior_shared_gain`` whenever it is a candidate, else ``cv``.

Development: seeds 0-47, the kept records that exist (``--keep``; every one holds each
candidate's per-fold scores; the CV of a candidate does not depend on the others, and seeds 0-11
run at 14:20 and again at 17:30 gave identical numbers for every common candidate): 0-23 from
the run that judged the shared adaptations, 24-35 from the member-weights run, 36-47 from the
no-fold run. Confirmation: seeds 48-59, new (``--seeds 48-59 --keep``). A variant **replaces the
CV's rule** only if (1) its share of scenarios within 15 % of the full plan from scratch on both
the validation MAE and the worst residual is **strictly higher** than ``cv``'s on the
confirmation seeds **and not lower** on the development seeds, and (2) on each of the two sets
its mean MAE ratio (pick / full plan) is not higher than ``cv``'s by more than **one standard
error** of the per-scenario differences (variant minus ``cv``) (``judge_default``). If both
variants qualify: the higher share on the confirmation seeds, then on the development seeds,
then the lower mean MAE ratio on the confirmation seeds, then ``shared_gain_unless_beaten``
(it keeps the CV's word when another candidate is clearly better). Otherwise ``cv`` stays.
Nothing is changed after the confirmation seeds are scored.
Development, seeds 0-47 (2026-11-29, the kept records copied into one directory, ``--seeds 0-47
--keep``): ``cv`` 20 of 48 within 15 % on both (on MAE 24, on worst 33; mean MAE ratio 1.439);
``shared_gain_unless_beaten`` 22 of 48 (26, 34; 1.388, difference -0.050, SE 0.048);
``always_shared_gain`` 22 of 48 (26, 34; 1.365, -0.074, SE 0.052). The two differ in seed 9 only
(a candidate beat the shared gain by more than one SE: ``prior_ridge``, 2.46 ; 1.87, where the
shared gain had 1.35 ; 1.25, both failing); against ``cv`` both pass seeds 17 (``cv``:
``prior_ridge``, 1.19 ; 1.07) and 40 (``cv``: ``ridge_global``, 1.24 ; 1.17), and none fails where
``cv`` passes.
Confirmation, seeds 48-59 (``--seeds 48-59 --keep``, the same code): ``cv`` 6 of 12 (on MAE 6,
on worst 10; 1.500); both variants 7 of 12 (7, 11; 1.280, difference -0.220, SE 0.221), the same
picks: seed 56 (a moved sensor; ``cv`` took ``ridge_global``, 3.71 ; 1.63) passes with the shared
gain (1.06 ; 0.82); seed 51 (``cv``: ``prior_gain``) passes with either. The criterion holds for
both with equal shares and the same confirmation mean: by its tie-break **``shared_gain_unless_beaten``
is the product's rule with an ensemble prior** (:func:`rafi.family.selection.choose_champion`). Over
all 60: 29 within 15 % on both against 26; the 80 % target is not reached at 4 h.

**Every member moved** (issue 47; criterion written 2026-11-30 before its run, in
``docs/decisions.md``). ``prior_shared_ridge``: every member of an ensemble prior re-fitted as the
shared gain times its coefficients plus a ridge move on its own features, one penalty by whole-run
CV; judged as G (the product's rule with it among the candidates) and H (it in the place of the
shared gain) against today, development seeds 0-47, confirmation 60-79. Today 22 of 48 and 8 of
20 within 15 % on both; G and H the same counts: **not adopted** (code and judge at git tag
``study/issue47-shared-ridge``). With three training runs the CV holds out a whole speed and
scores every move from the shared gain as an extrapolation (the candidate's CV score was worse than
the shared gain's on 42 of 48), while the validation runs lie between the training speeds.
The same candidate at one **fixed** penalty (10, chosen on seeds 0-47 with hindsight, the CV not
consulted; criterion written 2026-11-30 before seeds 80-99 were run), judged as G, H and A (always
it with an ensemble prior): today 22 of 48 and 10 of 20 within 15 % on both; G 22 and 10, H 22 and
10, **A 27 and 11** (mean MAE ratio 1.292 against 1.388 and 1.147 against 1.225, each more than two
SE lower): **A is the product's rule** (``judge_shared_ridge``, ``adopt_shared_ridge``). A+ (A
where today's rule offers the shared gain, else today's pick: the shared gain's safety net kept)
judged after it on new seeds 100-119 (``keep_the_net``): A 10 of 20, A+ 9, today 7; the net is
not kept. The moved members as the no-fold default (``--no-fold-hours 2``, :data:`NO_FOLD_MOVED`;
criterion 2026-11-30): development 36-47 6 of 12 against the shared gain's 7, confirmation
120-139 9 of 20 against 8: lower on the development seeds, the shared gain stays. The penalty set
by the shared gain (0.1 where it moved the prior by more than 10 %, else 10; criterion
2026-11-30), judged on new seeds 140-179 with a grid of the moves' penalties (scratch, not kept):
18 of 40 against the fixed penalty's 22, not adopted.

**A foreign prior declared a sibling** (``--false-siblings``, issue 47's "a foreign prior never
reaches promotion without a confirmation", in its hardest form): each random scenario of
``--seeds`` re-qualified from the OTHER base machine's champion, as if ``models.prior_siblings``
named it (the two twins share sensor names and probe map, so nothing refuses it). The table gives
what the product offers, its ratio to the full plan from scratch, the fitness warnings on it
(:func:`fitness_checks`) and whether the promotion is stopped; the summary counts the scenarios
stopped, and those stopped by a warning other than ``prior_speeds`` (which fires whenever the new
runs leave a speed of the prior untested, whatever the prior's origin).

**Another design declared a sibling** (``--other-designs``): the two twins are two designs, so a
rule for telling a sibling from another design judged on them says nothing about a third. For each
seed a random design of tapping-center-a's sensor layout
(:func:`rafi.twin.requalify_scenarios.random_design`: every constant and every sensor's lag and mix
weights times its own factor, spread 0.4) is qualified on its full plan; its champion re-qualifies
at 4 h a true sibling of it (the 4 % build spread) and another design declared a sibling
(:func:`~rafi.twin.requalify_scenarios.design_pair`). The table gives the fitness warnings, whether
the promotion is stopped, the ratio to the new machine's full plan, and the prior as it is on the
new runs over its own pooled 90 % half width (:func:`prior_misfit`; beyond
:data:`~rafi.family.prior_fitness.MISFIT_HALF_WIDTHS` the product's warning ``prior_misfit``).

Output: progress on stderr, a markdown table on stdout (docs/results.md's), and
``benchmarks/results/requalify.json`` (``--json`` to change; random scenarios:
``requalify_random.json`` and ``.md``). The runs are simulated clean at ``--sample-period``
(default 20 s) to keep it fast on two shared cores: minutes per scenario.
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as in workflow/scripts/compare.py: small matrices, one thread

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402

from rafi.artefact import write_text_atomic  # noqa: E402
from rafi.family.adapted import CANDIDATES, ENSEMBLE_CANDIDATES  # noqa: E402
from rafi.family.compare import compare_models, load_any, run_family  # noqa: E402
from rafi.family.prior_fitness import CHECKS, MISFIT_HALF_WIDTHS, prior_half_width  # noqa: E402
from rafi.family.selection import SIMPLICITY, selection_table  # noqa: E402
from rafi.ops.plan import plan_limits, plan_programme, prior_view  # noqa: E402
from rafi.settings import MACHINE_DEFAULTS  # noqa: E402
from rafi.twin.requalify_scenarios import (  # noqa: E402
    BASES,
    ISSUE_SCENARIOS,
    design_pair,
    issue_scenario,
    random_design,
    random_scenario,
)
from rafi.twin.scenarios import (  # noqa: E402
    KEY_SENSORS,
    SCENARIOS,
    RunSet,
    Scenario,
    TwinMachine,
    combine,
    make_scenario,
    noise_floor,
    noise_mae,
)

HOURS = (1.05, 2.0, 4.0, 8.0)
#: The issue's target: within this fraction of the full plan from scratch, at 4 h or less.
TARGET_FRACTION = 0.15
TARGET_HOURS = 4.0
TAKES_PRIOR = "prior" in inspect.signature(run_family).parameters
#: The adaptation candidates, simplest first (fewest numbers fitted on the new data: none, one
#: gain, a gain and a time factor, a ridge towards every coefficient); the from-scratch kinds
#: follow in :data:`rafi.family.selection.SIMPLICITY`'s order.
ADAPTATION_ORDER = (
    "prior",
    "prior_gain",
    "prior_shared_gain",
    "prior_time",
    "prior_shared_time",
    "prior_ridge",
    "prior_shared_ridge",
)
#: The shared adaptations judged (module docstring, "One shared adaptation"): the product offers
#: ``prior_shared_gain`` (:data:`rafi.family.adapted.ENSEMBLE_CANDIDATES`); ``prior_shared_time``
#: was judged beside it and stands in the kept records of that judgement only.
JUDGED_SHARED = ("prior_shared_gain", "prior_shared_time")
#: Every adaptation candidate (one model of the prior, or an ensemble prior as a whole).
ADAPTATIONS = (*CANDIDATES, *ENSEMBLE_CANDIDATES, "prior_shared_time")
#: The judgement of the shared adaptations: name -> the candidates it adds to today's.
SHARED = {"A: + prior_shared_gain": ("prior_shared_gain",), "B: + both": JUDGED_SHARED}
#: The no-fold defaults judged (module docstring, "The no-fold default"): the product's before
#: the judgement, and the one judged for an ensemble prior (a prior of one kind has no shared gain:
#: its own ``prior_gain`` stands for it).
NO_FOLD = ("prior_gain", "prior_shared_gain")
#: The no-fold default judged again once the moved members were offered (module docstring, "Every
#: member moved"): the shared gain against them.
NO_FOLD_MOVED = ("prior_shared_gain", "prior_shared_ridge")
#: The rules judged one level up on the random scenarios (module docstring, "The choice among
#: adaptations"): name -> what it does, for the record.
RULES = {
    "cv": "the lowest CV max abs residual score among every candidate (the product's rule until "
    "2026-11-29; with an ensemble prior the product now follows shared_gain_unless_beaten)",
    "one_se_simplest": "the simplest candidate whose CV score is within one standard error of the best's",
    "mean_and_worst": "the lowest mean of the CV's pooled RMSE and its mean held-out max abs residual",
    "adaptations_only": "with a prior, the CV's rule among the adaptation candidates only",
    "shared_gain_unless_beaten": "with an ensemble prior prior_shared_gain, unless a candidate's CV score is "
    "lower by more than one SE of the paired per-fold differences; else the CV's rule",
    "always_shared_gain": "prior_shared_gain whenever it is a candidate, else the CV's rule",
}
#: Every member of an ensemble prior moved toward the new data (module docstring, "Every member
#: moved"): judged by :func:`judge_shared_ridge`.
SHARED_RIDGE = "prior_shared_ridge"
#: The variants of the CV's rule judged by :func:`judge_default` (module docstring, "The shared
#: gain unless beaten"), in the order the criterion prefers between two that qualify.
DEFAULT_VARIANTS = ("shared_gain_unless_beaten", "always_shared_gain")


def progress(message: str) -> None:
    print(f"[bench_requalify {time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def fit_family(runs: RunSet, settings: dict, key_sensors, machine: str, kinds=None, prior=None) -> dict:
    """run_family on ``runs`` (as rule compare calls it); ``prior`` only when given."""
    options = dict(settings["models"], enabled=list(kinds or settings["models"]["enabled"]))
    extra = {"prior": prior} if prior is not None else {}
    return run_family(
        runs.table,
        runs.frame,
        key_sensors=list(key_sensors),
        terms=settings["fit"]["terms"],
        reference=settings["reference"],
        machine=machine,
        options=options,
        gates=settings["qualification"],
        hac_maxlags=settings["fit"]["hac_maxlags"],
        speed_tolerance_rpm=settings["speed_tolerance_rpm"],
        log=lambda m: None,
        **extra,
    )


def _mae(residuals, model: str) -> float:
    """Mean |measured - predicted| (um) of ``model`` over every validation sample."""
    r = residuals.loc[residuals["model"] == model, "residual_um"].astype(float)
    return float(r.abs().mean()) if r.notna().any() else math.nan


def _adaptation(model) -> dict:
    """What an adaptation candidate fitted (gain, time factor, ridge alpha); empty for the others."""
    out = {}
    for key, attr in (("gain", "gain_"), ("time_factor", "time_factor_"), ("alpha", "alpha_chosen_")):
        v = getattr(model, attr, None)
        if v is not None:
            out[key] = float(v)
    return out


def every_candidate(result: dict) -> dict:
    """Per candidate: its CV scores (what chose: the mean held-out max |residual|, the worst, the
    pooled RMSE, the selection score and each whole-run fold's max |residual|), its validation
    worst and MAE (um), its 90 % interval's coverage of the validation samples and mean width (um;
    read only, to report) and what an adaptation fitted. The plain ridge scored as a reference only
    (``candidate`` false) is not a candidate."""
    s = result["summary"]
    if "candidate" in s:
        s = s[s["candidate"].astype(bool)]
    s = s.set_index("model")
    cv = result["cv"]
    whole = cv[~cv["scheme"].astype(str).str.startswith("forward")] if "scheme" in cv else cv
    # the max |residual| score as rafi.family.selection scores it (the summary's may be re-scored
    # with a prior: rafi.family.adapted.prior_selection)
    plain = selection_table(cv, list(s.index)).set_index("model")["selection_score_um"]
    out = {}
    for m in s.index:

        def col(name, m=m):
            return float(s.loc[m, name]) if name in s and s.loc[m, name] is not None else math.nan

        folds = whole.loc[whole["model"] == m, "max_abs_after_um"].astype(float).tolist()
        out[m] = {
            "cv_mean_max_abs_um": col("cv_mean_max_abs_um"),
            "cv_max_abs_um": col("cv_max_abs_um"),
            "cv_rmse_um": col("cv_rmse_um"),
            "selection_score_um": float(plain.get(m, math.nan)),
            "cv_fold_max_abs_um": folds,
            "validation_um": float(s.loc[m, "max_abs_after_um"]),
            "validation_mae_um": _mae(result["residuals"], m),
            "validation_coverage": col("coverage"),
            "validation_interval_width_um": col("interval_width_um"),
        } | _adaptation(result["models"].get(m))
    return out


def prior_uncertainty(result: dict) -> dict[float, float]:
    """Speed -> the champion's whole-run CV max |residual| on the training run(s) held out at that
    speed (the worst where several): where the prior is least sure, from its own training CV."""
    cv = result["cv"]
    rows = cv[(cv["model"] == result["champion"]) & cv["test_speed_rpm"].notna()]
    return {float(k): float(v) for k, v in rows.groupby("test_speed_rpm")["max_abs_after_um"].max().items()}


def champion_errors(result: dict) -> tuple[float, float, str]:
    """The champion's validation MAE and worst residual (um) and its name."""
    s = result["summary"]
    row = s.loc[s["model"] == result["champion"]].iloc[0]
    return (
        _mae(result["residuals"], result["champion"]),
        float(row["max_abs_after_um"]),
        str(result["champion"]),
    )


def champion_worst(result: dict) -> tuple[float, str]:
    """The champion's worst validation residual (um) and its name."""
    _, worst, name = champion_errors(result)
    return worst, name


def unchanged_errors(prior: dict, validation: RunSet, gates: dict) -> tuple[float, float]:
    """The prior as it is on the validation runs: MAE and worst max |residual| (um)."""
    table, residuals = compare_models(
        {"prior": load_any(prior)}, validation.table, validation.frame, gates, return_residuals=True
    )
    return _mae(residuals, "prior"), float(table.loc[table["scope"] == "model", "max_abs_after_um"].iloc[0])


def unchanged_worst(prior: dict, validation: RunSet, gates: dict) -> float:
    """The prior as it is on the validation runs: worst max |residual| (um)."""
    return unchanged_errors(prior, validation, gates)[1]


def plan_for(prior: dict, speeds, hours: float, settings: dict):
    """The programme ``rafi plan --hours`` writes with ``prior`` (as :mod:`rafi.ops.plan_cli`:
    the plan shaped by the prior, its transient from the prior's interval)."""
    limits = plan_limits(settings)
    limits["transient_s"] = float(
        ((prior or {}).get("interval") or {}).get("transient_s") or limits["transient_s"]
    )
    view = prior_view(prior, tolerance_rpm=float(settings["speed_tolerance_rpm"]))
    return plan_programme(speeds_rpm=speeds, budget_h=hours, prior=view, **limits)


def qualify_old(sc, settings: dict, kinds=None) -> tuple[dict, list[float]]:
    """The old machine of scenario ``sc`` qualified on its full test plan: the family's fit
    (:func:`fit_family`) and its training speeds (r/min, sorted)."""
    old = sc.old_runs()
    fit = fit_family(old, settings, sc.key_sensors, sc.machine, kinds)
    speeds = sorted(float(v) for v in set(old.table.loc[old.table["role"] == "training", "speed_rpm"]))
    return fit, speeds


def fit_prior(machine: str, args, settings: dict, cache: dict) -> tuple:
    """The old machine's full qualification fitted (the prior): (artefact, champion, training
    speeds, CV by speed). The old machine's runs are those of the named scenarios at seed
    ``args.seed`` (the same in every scenario of a machine); kept in ``cache`` and, with
    ``--keep``, in ``prior-<machine>.json`` there."""
    if machine in cache:
        return cache[machine]
    keep = Path(args.keep) / f"prior-{machine}-seed{args.seed}.json" if getattr(args, "keep", None) else None
    if keep is not None and keep.exists():
        d = json.loads(keep.read_text())
        cache[machine] = (
            d["artefact"],
            d["champion"],
            d["speeds"],
            {float(k): v for k, v in d["cv"].items()},
        )
        return cache[machine]
    progress(f"{machine}: fitting the old machine's full qualification (the prior)")
    sc = make_scenario(SCENARIOS[0], machine, seed=args.seed, sample_period_s=args.sample_period)
    fit, speeds = qualify_old(sc, settings, args.kinds)
    cache[machine] = (fit["best_artefact"], fit["champion"], speeds, prior_uncertainty(fit))
    if keep is not None:
        a, c, sp, u = cache[machine]
        write_text_atomic(
            keep, json.dumps({"artefact": a, "champion": c, "speeds": sp, "cv": u}, default=float)
        )
    return cache[machine]


def one_scenario(name: str, args, settings: dict, old_fit_cache: dict) -> dict:
    """Every number of one scenario (see the module docstring)."""
    sc = make_scenario(name, args.machine, seed=args.seed, sample_period_s=args.sample_period)
    prior, prior_kind, speeds, uncertainty = fit_prior(args.machine, args, settings, old_fit_cache)
    validation = sc.new_validation()
    out = {
        "scenario": name,
        "prior_champion": prior_kind,
        "prior_cv_by_speed_um": uncertainty,
        "floor_um": noise_floor(validation),
    }
    out["unchanged_mae_um"], out["unchanged_um"] = unchanged_errors(
        prior, validation, settings["qualification"]
    )
    progress(f"{name}: full plan from scratch")
    out["full_mae_um"], out["full_um"], out["full_choice"] = champion_errors(
        fit_family(
            combine(sc.new_full_training(), validation), settings, sc.key_sensors, args.machine, args.kinds
        )
    )
    out["hours"] = []
    for hours in args.hours:
        plan = plan_for(prior, speeds, hours, settings)
        data = combine(sc.plan_runs(plan), validation)
        row = {"budget_h": hours, "plan_h": plan.attrs["total_h"], "speeds_rpm": plan.attrs["speeds_rpm"]}
        row["training_runs"] = int((data.table["role"] == "training").sum())
        progress(f"{name}: {hours:g} h ({row['training_runs']} training runs) from scratch")
        scratch = fit_family(data, settings, sc.key_sensors, args.machine, args.kinds)
        row["scratch_mae_um"], row["scratch_um"], row["scratch_choice"] = champion_errors(scratch)
        row["prior_mae_um"], row["prior_um"], row["prior_choice"] = math.nan, math.nan, None
        row["candidates"] = every_candidate(scratch)
        if TAKES_PRIOR:
            progress(f"{name}: {hours:g} h with the prior")
            adapted = fit_family(data, settings, sc.key_sensors, args.machine, args.kinds, prior=prior)
            row["prior_mae_um"], row["prior_um"], row["prior_choice"] = champion_errors(adapted)
            row["candidates"] = every_candidate(adapted)
        out["hours"].append(row)
    return out


def verdict(result: dict) -> str:
    """The issue's target on one scenario, in words, for every budget of 4 h or less (none is
    picked: a budget is the user's choice, made before any validation run is seen): within 15 %
    of the full plan from scratch on the worst residual and, where measured, on the MAE."""
    limit = result["full_um"] * (1 + TARGET_FRACTION)
    mae_limit = result.get("full_mae_um", math.nan) * (1 + TARGET_FRACTION)
    parts = []
    for r in result["hours"]:
        if r["budget_h"] > TARGET_HOURS or not math.isfinite(r["prior_um"]):
            continue
        within = "within" if _within(r, limit, mae_limit) else "NOT within"
        better = "better" if r["prior_um"] < r["scratch_um"] else "NOT better"
        mae = (
            f"MAE {r['prior_mae_um']:.2f} ; worst " if math.isfinite(r.get("prior_mae_um", math.nan)) else ""
        )
        parts.append(
            f"{r['budget_h']:g} h: {mae}{r['prior_um']:.2f} um, {within} 15 %, {better} than from scratch "
            f"({r['scratch_um']:.2f} um)"
        )
    if not parts:
        return "target not judged (no run with the prior at 4 h or less)"
    met = [
        r["budget_h"] for r in result["hours"] if r["budget_h"] <= TARGET_HOURS and _met(r, limit, mae_limit)
    ]
    head = f"met at {', '.join(f'{h:g} h' for h in met)}" if met else "NOT met"
    full = f"MAE {result['full_mae_um']:.2f} ; worst " if math.isfinite(mae_limit) else ""
    lim = f"{mae_limit:.2f} ; {limit:.2f}" if math.isfinite(mae_limit) else f"{limit:.2f}"
    return f"{head} (full plan {full}{result['full_um']:.2f} um, 15 % limit {lim} um): " + "; ".join(parts)


def _within(row: dict, limit: float, mae_limit: float = math.nan) -> bool:
    """The worst residual within ``limit`` and the MAE within ``mae_limit`` (when both are numbers)."""
    mae = row.get("prior_mae_um", math.nan)
    mae_ok = not (math.isfinite(mae_limit) and math.isfinite(mae)) or mae <= mae_limit
    return math.isfinite(row["prior_um"]) and row["prior_um"] <= limit and mae_ok


def _met(row: dict, limit: float, mae_limit: float = math.nan) -> bool:
    return _within(row, limit, mae_limit) and row["prior_um"] < row["scratch_um"]


def um(v) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.2f}"


def both(mae, worst) -> str:
    """``MAE ; worst`` (um)."""
    return f"{um(mae)} ; {um(worst)}"


def markdown(results: list[dict]) -> str:
    """docs/results.md's table: one row per scenario and budget, MAE ; worst residual (um)."""
    lines = [
        "| scenario | new data (h) | runs | from scratch, MAE ; worst (um) | CV chose "
        "| with the prior, MAE ; worst (um) | CV chose | full plan from scratch, MAE ; worst (um) "
        "| prior unchanged, MAE ; worst (um) "
        "| noise floor (um) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for res in results:
        for i, r in enumerate(res["hours"]):
            beside = (
                [
                    f"{both(res.get('full_mae_um'), res['full_um'])} ({res['full_choice']})",
                    both(res.get("unchanged_mae_um"), res["unchanged_um"]),
                    um(res["floor_um"]),
                ]
                if i == 0
                else ["", "", ""]
            )
            lines.append(
                "| "
                + " | ".join(
                    [
                        res["scenario"] if i == 0 else "",
                        f"{r['plan_h']:.2f}",
                        str(r["training_runs"]),
                        both(r.get("scratch_mae_um"), r["scratch_um"]),
                        r["scratch_choice"],
                        both(r.get("prior_mae_um"), r["prior_um"]),
                        r["prior_choice"] or "-",
                        *beside,
                    ]
                )
                + " |"
            )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- random scenarios


def parse_seeds(random_n: int | None, seeds: str | None) -> list[int]:
    """The seeds of ``--random N`` (0..N-1) and ``--seeds A-B`` (A..B, both included; or one
    number), in order, each once."""
    out = list(range(int(random_n))) if random_n else []
    if seeds:
        a, _, b = str(seeds).partition("-")
        lo, hi = int(a), int(b or a)
        if hi < lo:
            raise ValueError(f"--seeds {seeds}: expected A-B with A <= B")
        out += [s for s in range(lo, hi + 1) if s not in out]
    return out


def _scratch_pick(cands: dict) -> str | None:
    """The CV's pick among the from-scratch candidates (what a fit on the same hours with no prior
    would choose: each candidate's CV does not depend on the others)."""
    pool = {m: c for m, c in cands.items() if m not in ADAPTATIONS}
    return _lowest(pool, lambda c: c["selection_score_um"])


def _lowest(pool: dict, score) -> str | None:
    """The candidate of ``pool`` with the lowest finite ``score``; ties to the simpler one."""
    finite = [(score(c), _order(m), m) for m, c in pool.items() if math.isfinite(score(c))]
    return min(finite)[2] if finite else None


def _order(model: str) -> int:
    """Simplicity rank: the adaptations first (:data:`ADAPTATION_ORDER`), then the from-scratch
    kinds (:data:`rafi.family.selection.SIMPLICITY`)."""
    if model in ADAPTATION_ORDER:
        return ADAPTATION_ORDER.index(model)
    return len(ADAPTATION_ORDER) + SIMPLICITY.get(model, len(SIMPLICITY))


def rule_pick(rule: str, cands: dict, cv_choice: str | None = None) -> str | None:
    """The candidate rule ``rule`` (:data:`RULES`) picks from the per-candidate CV scores
    ``cands`` (:func:`every_candidate`); ``cv_choice`` (the product's pick as recorded) is not
    used: every rule is recomputed from the candidates' scores."""
    if rule == "cv":
        return _lowest(cands, lambda c: c["selection_score_um"])
    if rule == "mean_and_worst":
        return _lowest(cands, lambda c: 0.5 * (c["cv_rmse_um"] + c["cv_mean_max_abs_um"]))
    if rule == "adaptations_only":
        pool = {m: c for m, c in cands.items() if m in ADAPTATIONS}
        return _lowest(pool or cands, lambda c: c["selection_score_um"])
    if rule == "always_shared_gain" and "prior_shared_gain" in cands:
        return "prior_shared_gain"
    if rule == "shared_gain_unless_beaten" and "prior_shared_gain" in cands:
        return shared_gain_unless_beaten(cands)
    if rule in ("always_shared_gain", "shared_gain_unless_beaten"):
        return _lowest(cands, lambda c: c["selection_score_um"])
    if rule == "one_se_simplest":
        best = _lowest(cands, lambda c: c["selection_score_um"])
        if best is None:
            return None
        folds = [v for v in cands[best]["cv_fold_max_abs_um"] if math.isfinite(v)]
        se = float(np.std(folds, ddof=1) / math.sqrt(len(folds))) if len(folds) > 1 else 0.0
        bound = cands[best]["selection_score_um"] + se
        ok = [
            m
            for m, c in cands.items()
            if math.isfinite(c["selection_score_um"]) and c["selection_score_um"] <= bound
        ]
        return min(ok, key=lambda m: (_order(m), m))
    raise ValueError(f"unknown rule {rule!r}; known: {', '.join(RULES)}")


def paired_se(a, b) -> float:
    """The standard error of the mean of the paired differences ``a - b`` (fold by fold; NaN with
    fewer than two finite pairs)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d = d[np.isfinite(d)]
    return float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.nan


def shared_gain_unless_beaten(cands: dict, reference: str = "prior_shared_gain") -> str | None:
    """``reference`` (``prior_shared_gain``) unless a candidate's CV score is lower than its by more
    than one standard error of the paired per-fold differences (``cv_fold_max_abs_um``, the same
    whole-run folds in the same order for every candidate); then the lowest CV score among those
    that beat it so (module docstring, "The shared gain unless beaten")."""
    ref = cands[reference]
    if not math.isfinite(ref["selection_score_um"]):
        return _lowest(cands, lambda c: c["selection_score_um"])
    beat = {}
    for m, c in cands.items():
        if m == reference or not math.isfinite(c["selection_score_um"]):
            continue
        folds, ref_folds = c.get("cv_fold_max_abs_um", []), ref.get("cv_fold_max_abs_um", [])
        if len(folds) != len(ref_folds):
            continue
        se = paired_se(folds, ref_folds)
        if math.isfinite(se) and ref["selection_score_um"] - c["selection_score_um"] > se:
            beat[m] = c
    return _lowest(beat, lambda c: c["selection_score_um"]) if beat else reference


def offered(cands: dict) -> dict:
    """The candidates the product offers today: a kept record's judged-only adaptations
    (``prior_shared_time``, ``prior_member_weights``) dropped."""
    today = (*CANDIDATES, *ENSEMBLE_CANDIDATES)
    return {m: c for m, c in cands.items() if not m.startswith("prior") or m in today}


def ratio_row(picks: dict, r: list) -> dict:
    """A candidate set's or rule's figures on the scenarios: its ``picks``, the MAE and worst
    ratios ``r`` to the full plan (one pair per scenario, in order), the shares within 15 % on
    MAE, on worst and on both, ``n_both`` and the mean MAE ratio."""
    n = max(len(r), 1)
    return {
        "picks": picks,
        "mae_ratio": [m for m, _ in r],
        "worst_ratio": [w for _, w in r],
        "share_mae": sum(m <= 1 + TARGET_FRACTION for m, _ in r) / n,
        "share_worst": sum(w <= 1 + TARGET_FRACTION for _, w in r) / n,
        "share_both": sum(passes(m, w) for m, w in r) / n,
        "n_both": sum(passes(m, w) for m, w in r),
        "mean_mae_ratio": float(np.mean([m for m, _ in r])) if r else math.nan,
    }


def with_difference(row: dict, base: dict) -> dict:
    """``row`` with the mean and standard error of its per-scenario MAE ratio differences against
    ``base``'s (``mean_mae_difference``, ``se_mae_difference``)."""
    d = np.array(row["mae_ratio"]) - np.array(base["mae_ratio"])
    row["mean_mae_difference"] = float(d.mean()) if d.size else math.nan
    row["se_mae_difference"] = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.nan
    return row


def judge_default(results: list[dict], variants=DEFAULT_VARIANTS) -> dict:
    """``cv`` and each rule of ``variants`` on ``results`` (module docstring, "The shared gain
    unless beaten"), every rule among the candidates offered today (:func:`offered`): per rule the
    picks, the MAE and worst ratios to the full plan, the shares within 15 % on MAE, on worst and on
    both, the mean MAE ratio and, for a variant, the mean and SE of the per-scenario MAE ratio
    differences (variant minus ``cv``) and ``mae_ok`` (the mean not higher than one SE)."""

    def row(rule: str) -> dict:
        chosen = {res["seed"]: rule_pick(rule, offered(res["candidates"])) for res in results}
        return ratio_row(chosen, [ratios(res, chosen[res["seed"]]) for res in results])

    cv = row("cv")
    out = {"cv": cv}
    for rule in variants:
        v = with_difference(row(rule), cv)
        v["mae_ok"] = bool(v["mean_mae_difference"] <= v["se_mae_difference"] + 1e-12)
        out[rule] = v
    return out


def adopt_variant(development: dict, confirmation: dict, variants, base: str) -> str:
    """The variant of ``variants`` (in the order preferred between equals) the criteria of the
    rule judgements name against ``base`` (a row of both ``development`` and ``confirmation``):
    its share within 15 % on both strictly higher than ``base``'s on the confirmation seeds and
    not lower on the development seeds, its mean MAE ratio within one SE of ``base``'s on both
    (``mae_ok``); between two, the higher confirmation share, then development share, then the
    lower confirmation mean MAE ratio, then the earlier in ``variants``; else ``base``."""
    variants = [v for v in variants if v in confirmation and v in development]
    ok = [
        v
        for v in variants
        if confirmation[v]["share_both"] > confirmation[base]["share_both"]
        and development[v]["share_both"] >= development[base]["share_both"]
        and confirmation[v]["mae_ok"]
        and development[v]["mae_ok"]
    ]
    if not ok:
        return base
    return min(
        ok,
        key=lambda v: (
            -confirmation[v]["share_both"],
            -development[v]["share_both"],
            confirmation[v]["mean_mae_ratio"],
            variants.index(v),
        ),
    )


def adopt_default(development: dict, confirmation: dict) -> str:
    """The rule the criterion names from :func:`judge_default` on the development and the
    confirmation seeds (:func:`adopt_variant` of :data:`DEFAULT_VARIANTS` against ``cv``)."""
    return adopt_variant(development, confirmation, DEFAULT_VARIANTS, "cv")


def difference_cells(v: dict, verdict: str) -> tuple[str, str]:
    """A judged row's last two table cells: its paired MAE ratio difference ``+d (se)`` (``-``
    for the baseline) and its ``verdict`` key as yes / no (``-`` where it has none)."""
    if "mean_mae_difference" not in v:
        return "-", ("yes" if v[verdict] else "no") if verdict in v else "-"
    diff = f"{v['mean_mae_difference']:+.3f} ({v['se_mae_difference']:.3f})"
    return diff, ("yes" if v[verdict] else "no") if verdict in v else "-"


def count_cells(v: dict, n: int) -> str:
    """A judged row's shares within 15 % on MAE, on worst and on both as ``k of n`` cells."""
    return f"{round(v['share_mae'] * n)} of {n} | {round(v['share_worst'] * n)} of {n} | {v['n_both']} of {n}"


def default_markdown(judged: dict) -> str:
    """:func:`judge_default`'s table: one row per rule, then the picks per scenario."""
    lines = [
        "| rule | within 15 % on MAE | on worst | on both | mean MAE ratio "
        "| vs the first row: mean difference (SE) | MAE not worse by > 1 SE |",
        "|---|---|---|---|---|---|---|",
    ]
    base = next(iter(judged.values()))
    n = len(base["picks"])
    for name, v in judged.items():
        diff, ok = difference_cells(v, "mae_ok")
        lines.append(f"| {name} | {count_cells(v, n)} | {v['mean_mae_ratio']:.3f} | {diff} | {ok} |")
    lines += ["", "| seed | " + " | ".join(f"{r}: pick, ratios MAE ; worst" for r in judged) + " |"]
    lines.append("|---|" + "---|" * len(judged))
    for i, seed in enumerate(base["picks"]):
        cells = [
            f"{v['picks'][seed]} {v['mae_ratio'][i]:.2f} ; {v['worst_ratio'][i]:.2f}"
            f"{'' if passes(v['mae_ratio'][i], v['worst_ratio'][i]) else ' x'}"
            for v in judged.values()
        ]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def one_random(
    seed: int,
    args,
    settings: dict,
    prior_cache: dict,
    scenario=None,
    prior_machine: str | None = None,
    prior_fit: tuple | None = None,
) -> dict:
    """Every number of random scenario ``seed`` (:func:`rafi.twin.requalify_scenarios.random_scenario`;
    or ``scenario``, a :class:`~rafi.twin.requalify_scenarios.RandomScenario` built otherwise) at
    ``args.budget`` h of new data (:data:`TARGET_HOURS` unless ``--budget``): the prior, the full
    plan from scratch and every candidate of the fit with the prior, each with its validation MAE
    and worst residual, and the fitness warnings on the champion. The prior is the base machine's
    champion, or ``prior_machine``'s (a prior from another machine, declared a sibling), or
    ``prior_fit`` (``(artefact, champion, training speeds)``, :func:`fit_design_prior`)."""
    budget = float(getattr(args, "budget", TARGET_HOURS))
    rs = scenario if scenario is not None else random_scenario(seed)
    sc = rs.scenario(args.sample_period)
    prior_of = prior_machine or rs.machine
    if prior_fit is not None:
        prior, prior_kind, speeds = prior_fit
    else:
        prior, prior_kind, speeds, _ = fit_prior(prior_of, args, settings, prior_cache)
    if prior_of != rs.machine:  # the plan tests this machine's speeds, whoever the prior is of
        speeds = fit_prior(rs.machine, args, settings, prior_cache)[2]
    validation = sc.new_validation()
    out = {"seed": int(seed), "machine": rs.machine, "change": rs.change, "truth": rs.truth}
    out["prior_machine"] = prior_of
    out |= {"prior_champion": prior_kind, "floor_um": noise_floor(validation)}
    half = prior_half_width(prior)
    out["prior_half_width_um"] = math.nan if half is None else half
    out["floor_mae_um"] = noise_mae(validation)
    out["unchanged_mae_um"], out["unchanged_um"] = unchanged_errors(
        prior, validation, settings["qualification"]
    )
    progress(f"seed {seed} ({rs.machine}, {rs.change}): full plan from scratch")
    full = fit_family(
        combine(sc.new_full_training(), validation), settings, sc.key_sensors, rs.machine, args.kinds
    )
    out["full_mae_um"], out["full_um"], out["full_choice"] = champion_errors(full)
    plan = plan_for(prior, speeds, budget, settings)
    reference = getattr(args, "plan_reference", "run_start")
    data = combine(sc.plan_runs(plan, reference=reference), validation)
    out |= {"budget_h": budget, "plan_h": plan.attrs["total_h"], "speeds_rpm": plan.attrs["speeds_rpm"]}
    out["plan_reference"] = reference
    out["training_runs"] = int((data.table["role"] == "training").sum())
    progress(f"seed {seed}: {budget:g} h ({out['training_runs']} training runs) with the prior")
    plan_settings = {**settings, "reference": {**settings["reference"], "rule": reference}}
    adapted = fit_family(data, plan_settings, sc.key_sensors, rs.machine, args.kinds, prior=prior)
    out["prior_mae_um"], out["prior_um"], out["prior_choice"] = champion_errors(adapted)
    out["warnings"] = fitness_checks(adapted["models"].get(adapted["champion"]))
    out["selection_basis"] = adapted.get("selection_basis")
    out["candidates"] = every_candidate(adapted)
    out["moved_with_gain_interval"] = borrowed_interval(
        adapted["residuals"], "prior_shared_ridge", "prior_shared_gain"
    )
    out["with_prior_gain_interval"] = {
        name: borrowed_interval(adapted["residuals"], name, "prior_gain")
        for name in ("prior_ridge", "prior_time")
    }
    pick = _scratch_pick(out["candidates"])
    c = out["candidates"].get(pick, {})
    out["scratch_choice"] = pick
    out["scratch_mae_um"], out["scratch_um"] = (
        c.get("validation_mae_um", math.nan),
        c.get("validation_um", math.nan),
    )
    return out


def borrowed_interval(residuals, model: str, lender: str) -> dict:
    """Coverage of the validation samples and mean width (um) of ``model``'s predictions with the
    half-widths of ``lender``'s 90 % interval at the same samples (a candidate interval for the
    moved members: the shared gain's calibration, the same prior and runs); NaN without both."""
    cols = ["run_id", "t_s", "residual_um", "lower_um", "upper_um"]
    a = residuals.loc[residuals["model"] == model, cols]
    b = residuals.loc[residuals["model"] == lender, cols]
    j = a.merge(b, on=["run_id", "t_s"], suffixes=("", "_lender"))
    half = (j["upper_um_lender"] - j["lower_um_lender"]).to_numpy(float) / 2.0
    res = j["residual_um"].to_numpy(float)
    ok = np.isfinite(half) & np.isfinite(res)
    if not ok.any():
        return {"coverage": math.nan, "width_um": math.nan}
    return {
        "coverage": float(np.mean(np.abs(res[ok]) <= half[ok])),
        "width_um": float(np.mean(2.0 * half[ok])),
    }


def fitness_checks(model) -> list[str]:
    """The checks (:data:`rafi.family.prior_fitness.CHECKS`) of ``model``'s fitness warnings, in
    their order; none for a model that is not an adaptation of a prior. Any of them blocks the
    promotion until an engineer confirms it."""
    block = getattr(model, "fitness_", None) or {}
    return [str(w.get("check")) for w in block.get("warnings") or [] if w.get("check") in CHECKS]


#: The warning that fires whenever the new runs leave a speed of the prior untested: at a 4 h
#: budget nearly always, so it tells a foreign prior from this machine's by nothing.
UNTESTED_SPEEDS = "prior_speeds"


def other_base(machine: str) -> str:
    """The base machine of :data:`rafi.twin.requalify_scenarios.BASES` that is not ``machine``."""
    others = [b for b in BASES if b != machine]
    if not others:
        raise ValueError(f"no base machine other than {machine!r} in {BASES}")
    return others[0]


def _with_prior_cells(res: dict) -> str:
    """The cells ``| MAE ; worst | ratios to the full plan`` of the model offered with the prior."""
    m, w = res["prior_mae_um"] / res["full_mae_um"], res["prior_um"] / res["full_um"]
    return f"| {both(res['prior_mae_um'], res['prior_um'])} | {m:.2f} ; {w:.2f}"


def _warned_on_prior(res: dict) -> bool:
    """Whether a record's fitness warnings hold one other than :data:`UNTESTED_SPEEDS`: one that
    points at the prior, not at the speeds the new runs left untested."""
    return bool(set(res.get("warnings") or []) - {UNTESTED_SPEEDS})


def _stopped_cells(res: dict) -> str:
    """The cells ``| fitness warnings | promotion stopped |`` of a record."""
    checks = res.get("warnings") or []
    return f"| {', '.join(checks) or 'none'} | {'yes' if checks else '**NO**'} |"


def false_sibling_markdown(results: list[dict]) -> str:
    """One row per scenario whose prior came from the other base machine, declared a sibling:
    how the product did on the changed machine's validation runs, the warnings on its champion,
    whether the promotion is stopped; then how many were stopped, and by what."""
    h = f"{_budget_of(results):g} h"
    lines = [
        f"| seed | machine | change | prior of | CV chose | {h} with this prior, MAE ; worst (um) | "
        "ratio to the full plan from scratch, MAE ; worst | fitness warnings | promotion stopped |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for res in results:
        lines.append(
            f"| {res['seed']} | {res['machine']} | {res['change']} | {res['prior_machine']} "
            f"| {res['prior_choice']} {_with_prior_cells(res)} {_stopped_cells(res)}"
        )
    stopped = [r for r in results if r.get("warnings")]
    told = [r for r in results if _warned_on_prior(r)]
    missed = [str(r["seed"]) for r in results if not r.get("warnings")]
    lines += [
        "",
        f"Promotion stopped until confirmed: {len(stopped)} of {len(results)} scenarios "
        f"(not stopped: {', '.join(missed) or 'none'}); by a warning other than `{UNTESTED_SPEEDS}` "
        f"(which fires whenever the new runs leave a speed of the prior untested, whatever the "
        f"prior's origin): {len(told)} of {len(results)}.",
    ]
    return "\n".join(lines)


def ratios(res: dict, pick: str | None) -> tuple[float, float]:
    """(MAE, worst) of candidate ``pick`` over the full plan from scratch's."""
    c = res["candidates"].get(pick) if pick else None
    if not c or "validation_mae_um" not in c:
        return math.nan, math.nan
    return c["validation_mae_um"] / res["full_mae_um"], c["validation_um"] / res["full_um"]


def passes(mae_ratio: float, worst_ratio: float, fraction: float = TARGET_FRACTION) -> bool:
    """Within ``fraction`` (:data:`TARGET_FRACTION`) of the full plan from scratch on both MAE and
    worst."""
    limit = 1 + fraction
    return (
        math.isfinite(mae_ratio)
        and math.isfinite(worst_ratio)
        and mae_ratio <= limit
        and worst_ratio <= limit
    )


def judge_rules(results: list[dict], rules=tuple(RULES)) -> dict:
    """Every rule of ``rules`` on the random scenarios ``results``: its ``share`` of scenarios within
    15 % on both, its ``mean_ratio`` (mean over scenarios of the mean of the MAE and worst ratios),
    ``failed`` (the seeds it misses) and ``picks``; ``winner``: the rule the criterion names
    (module docstring: the highest share, ties to the lower mean ratio; the product's ``cv`` stays
    unless another rule is strictly better)."""
    out = {}
    for rule in rules:
        picks, ok, rs = {}, [], []
        for res in results:
            pick = rule_pick(rule, res["candidates"], res["prior_choice"])
            m, w = ratios(res, pick)
            picks[res["seed"]] = pick
            ok.append(passes(m, w))
            rs.append(0.5 * (m + w))
        finite = [v for v in rs if math.isfinite(v)]
        out[rule] = {
            "share": sum(ok) / len(results) if results else math.nan,
            "mean_ratio": float(np.mean(finite)) if finite else math.nan,
            "failed": [r["seed"] for r, good in zip(results, ok) if not good],
            "picks": picks,
        }
    best = "cv" if "cv" in out else next(iter(out), None)
    for rule, v in out.items():
        b = out[best]
        if v["share"] > b["share"] or (
            v["share"] == b["share"] and v["mean_ratio"] < b["mean_ratio"] - 1e-12
        ):
            best = rule
    return {"rules": out, "winner": best}


def _budget_of(results: list[dict]) -> float:
    """The hours of new data of the random scenarios ``results`` (one budget per run)."""
    return float(results[0].get("budget_h", TARGET_HOURS)) if results else TARGET_HOURS


def random_markdown(results: list[dict]) -> str:
    """One row per random scenario at its budget of new data, then the share that pass."""
    h = f"{_budget_of(results):g} h"
    lines = [
        f"| seed | machine | change | truth | full plan from scratch, MAE ; worst (um) | {h} with the prior, "
        f"MAE ; worst (um) | ratio to full, MAE ; worst | CV chose | {h} from scratch, MAE ; worst (um) "
        "| prior unchanged, MAE ; worst (um) | within 15 % on both |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for res in results:
        m, w = res["prior_mae_um"] / res["full_mae_um"], res["prior_um"] / res["full_um"]
        lines.append(
            f"| {res['seed']} | {res['machine']} | {res['change']} | {truth_text(res['truth'])} "
            f"| {both(res['full_mae_um'], res['full_um'])} ({res['full_choice']}) "
            f"| {both(res['prior_mae_um'], res['prior_um'])} | {m:.2f} ; {w:.2f} | {res['prior_choice']} "
            f"| {both(res['scratch_mae_um'], res['scratch_um'])} ({res['scratch_choice']}) "
            f"| {both(res['unchanged_mae_um'], res['unchanged_um'])} "
            f"| {'yes' if passes(m, w) else '**NO**'} |"
        )
    n_pass = sum(passes(r["prior_mae_um"] / r["full_mae_um"], r["prior_um"] / r["full_um"]) for r in results)
    failed = [
        str(r["seed"])
        for r in results
        if not passes(r["prior_mae_um"] / r["full_mae_um"], r["prior_um"] / r["full_um"])
    ]
    lines.append("")
    lines.append(
        f"Within 15 % of the full plan on both MAE and worst: {n_pass} of {len(results)} scenarios "
        f"({100.0 * n_pass / max(len(results), 1):.0f} %); fail: {', '.join(failed) or 'none'}."
    )
    lines += ["", by_change_markdown(results), "", tolerance_markdown(results)]
    floor = noise_floor_line(results)
    if floor:
        lines += ["", floor]
    return "\n".join(lines)


def _passes_as(res: dict, mae_key: str, worst_key: str, fraction: float = TARGET_FRACTION) -> bool:
    return passes(res[mae_key] / res["full_mae_um"], res[worst_key] / res["full_um"], fraction)


#: The tolerances of :func:`tolerance_markdown`: the target's 15 % and looser ones.
TOLERANCES = (0.15, 0.2, 0.25, 0.3, 0.4, 0.5)


def tolerance_markdown(results: list[dict], fractions=TOLERANCES) -> str:
    """What the target asks: per tolerance (a fraction of the full plan from scratch, on both MAE
    and worst), how many scenarios are within it with the prior (the product's pick), with the
    prior unchanged, from scratch on the same hours, and with the best candidate in hindsight; with
    ``--repeat-full`` (:func:`has_repeat`) also a second full plan from scratch on the same machine
    (what the reference itself reaches when it is run again)."""
    h = f"{_budget_of(results):g} h"
    n = len(results)
    repeat = has_repeat(results)
    lines = [
        f"| within, on both | {h} with the prior | prior unchanged | {h} from scratch "
        "| best candidate in hindsight |" + (" the full plan again |" if repeat else ""),
        "|---|---|---|---|---|" + ("---|" if repeat else ""),
    ]
    for f in fractions:
        counts = [
            sum(_passes_as(r, "prior_mae_um", "prior_um", f) for r in results),
            sum(_passes_as(r, "unchanged_mae_um", "unchanged_um", f) for r in results),
            sum(_passes_as(r, "scratch_mae_um", "scratch_um", f) for r in results),
            sum(any(passes(*ratios(r, k), f) for k in r["candidates"]) for r in results),
        ]
        if repeat:
            counts.append(sum(_passes_as(r, *REPEAT_KEYS, f) for r in results))
        cells = [f"{c} of {n} ({100.0 * c / max(n, 1):.0f} %)" for c in counts]
        lines.append(f"| {100 * f:g} % | " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: The record's keys of a second full plan from scratch (``--repeat-full``): its validation MAE and
#: worst residual.
REPEAT_KEYS = ("repeat_full_mae_um", "repeat_full_um")


def has_repeat(results: list[dict]) -> bool:
    """Whether every record of ``results`` holds a second full plan from scratch (``--repeat-full``)."""
    return bool(results) and all(k in r for r in results for k in REPEAT_KEYS)


def by_change_markdown(results: list[dict]) -> str:
    """Where the misses are: per base machine and kind of change, how many scenarios are within 15 %
    of the full plan on both MAE and worst with the prior (the product's pick), with the prior
    unchanged, from scratch on the same hours, and with the best candidate in hindsight (any
    candidate of the fit whose validation figures pass: the ceiling of a choice among them)."""
    cells: dict[tuple[str, str], list[dict]] = {}
    for res in results:
        cells.setdefault((res["machine"], res["change"]), []).append(res)
    h = f"{_budget_of(results):g} h"
    repeat = has_repeat(results)
    lines = [
        f"| base machine | change | scenarios | {h} with the prior | prior unchanged | {h} from scratch "
        "| best candidate in hindsight |" + (" the full plan again |" if repeat else ""),
        "|---|---|---|---|---|---|---|" + ("---|" if repeat else ""),
    ]
    totals = [0, 0, 0, 0, 0] + ([0] if repeat else [])
    for (machine, change), rs in sorted(cells.items()):
        counts = [
            len(rs),
            sum(_passes_as(r, "prior_mae_um", "prior_um") for r in rs),
            sum(_passes_as(r, "unchanged_mae_um", "unchanged_um") for r in rs),
            sum(_passes_as(r, "scratch_mae_um", "scratch_um") for r in rs),
            sum(any(passes(*ratios(r, k)) for k in r["candidates"]) for r in rs),
        ]
        if repeat:
            counts.append(sum(_passes_as(r, *REPEAT_KEYS) for r in rs))
        totals = [t + c for t, c in zip(totals, counts)]
        lines.append(f"| {machine} | {change} | " + " | ".join(map(str, counts)) + " |")
    lines.append("| all | | " + " | ".join(map(str, totals)) + " |")
    return "\n".join(lines)


def noise_floor_line(results: list[dict]) -> str | None:
    """How the MAE target compares with the noise: over the scenarios whose model with the prior misses 15 %
    of the full plan's MAE, the median excess over the full plan's MAE in um and as a share of the
    validation noise's own MAE (``floor_mae_um``: a perfect model's MAE, :func:`noise_mae`);
    ``None`` when no scenario misses on MAE or the kept seeds predate ``floor_mae_um``."""
    missed = [
        r
        for r in results
        if r["prior_mae_um"] > r["full_mae_um"] * (1 + TARGET_FRACTION)
        and math.isfinite(r.get("floor_mae_um", math.nan))
    ]
    if not missed:
        return None
    excess = np.array([r["prior_mae_um"] - r["full_mae_um"] for r in missed])
    floor = np.array([r["floor_mae_um"] for r in missed])
    full = np.array([r["full_mae_um"] for r in missed])
    return (
        f"The noise: on the {len(missed)} scenarios whose {_budget_of(results):g} h model misses 15 % "
        "on MAE, it is above the "
        f"full plan's MAE by a median {np.median(excess):.3f} um ({np.median(excess / floor):.0%} of the "
        f"validation noise's own MAE, a perfect model's, median {np.median(floor):.3f} um; the full "
        f"plan's MAE is a median {np.median(full / floor):.2f} x that noise MAE)."
    )


def truth_text(truth: dict) -> str:
    """The change's size in a few words (the table's ``truth`` column)."""
    change = truth["change"]
    if change == "repair":
        gains = ", ".join(f"{k} x{v:.2f}" for k, v in truth["gain_factors"].items())
        return f"capacities x{truth['capacity_factor']:.2f}, gain {gains}"
    if change == "sibling":
        gains = ", ".join(f"{k} x{v:.2f}" for k, v in truth["gain_factors"].items())
        return f"gain {gains}, room {truth['room_shift_c']:+.1f} K"
    if change == "season":
        return (
            f"room {truth['room_shift_c']:+.1f} K, swing {truth['daily_amplitude_c']:.1f} K, "
            f"cooler {truth['cooler_offset_c']:+.1f} K"
        )
    return (
        f"{truth['sensor']} {truth['moved_share']:.0%} {truth['from_node']}->{truth['to_node']}, "
        f"lag x{truth['lag_factor']:.2f}, offset {truth['offset_shift_c']:+.2f} K"
    )


def rules_markdown(judged: dict) -> str:
    """The rules judged one level up: share within 15 % on both, mean ratio, the seeds missed."""
    lines = [
        "| rule | what it picks | share within 15 % on both | mean ratio to full | fails |",
        "|---|---|---|---|---|",
    ]
    for rule, v in judged["rules"].items():
        lines.append(
            f"| {rule} | {RULES[rule]} | {100 * v['share']:.0f} % | {v['mean_ratio']:.3f} "
            f"| {', '.join(map(str, v['failed'])) or 'none'} |"
        )
    lines.append(f"\nBy the criterion: **{judged['winner']}**.")
    return "\n".join(lines)


def judge_shared_ridge(results: list[dict]) -> dict:
    """Every member of an ensemble prior moved toward the new data, judged (module docstring,
    "Every member moved"): ``today``, the product's rule (``shared_gain_unless_beaten``) among the
    candidates offered before :data:`SHARED_RIDGE`; ``G``, the same rule with it among them; ``H``,
    the rule with it in the place of ``prior_shared_gain``; ``A``, it whenever it is a candidate.
    Per row :func:`ratio_row`'s figures, and for G, H and A the mean and SE of the per-scenario MAE
    ratio differences against today and ``mae_ok`` (the mean not higher than one SE)."""

    def pool(res: dict, with_new: bool) -> dict:
        cands = offered(res["candidates"])
        return cands if with_new else {m: c for m, c in cands.items() if m != SHARED_RIDGE}

    def pick(res: dict, variant: str) -> str | None:
        if variant == "H" and SHARED_RIDGE in res["candidates"]:
            return shared_gain_unless_beaten(pool(res, True), reference=SHARED_RIDGE)
        if variant == "A" and SHARED_RIDGE in res["candidates"]:
            return SHARED_RIDGE
        if variant == "A+" and SHARED_RIDGE in res["candidates"]:
            today = rule_pick("shared_gain_unless_beaten", pool(res, False))
            return SHARED_RIDGE if today == "prior_shared_gain" else today
        return rule_pick("shared_gain_unless_beaten", pool(res, variant != "today"))

    def row(variant: str) -> dict:
        chosen = {res["seed"]: pick(res, variant) for res in results}
        return ratio_row(chosen, [ratios(res, chosen[res["seed"]]) for res in results])

    today = row("today")
    out = {"today": today}
    for variant, name in (
        ("G", "G: + prior_shared_ridge"),
        ("H", "H: prior_shared_ridge unless beaten"),
        ("A", "A: always prior_shared_ridge"),
        ("A+", "A+: prior_shared_ridge where today's rule offers prior_shared_gain"),
    ):
        v = with_difference(row(variant), today)
        v["mae_ok"] = bool(v["mean_mae_difference"] <= v["se_mae_difference"] + 1e-12)
        out[name] = v
    return out


def adopt_shared_ridge(development: dict, confirmation: dict) -> str:
    """What the criterion of "Every member moved" names from :func:`judge_shared_ridge` on the
    development and the confirmation seeds: :func:`adopt_variant` of G, H and A against
    ``today`` (A+ is judged apart, :func:`keep_the_net`)."""
    variants = [name for name in confirmation if name[:2] in ("G:", "H:", "A:")]
    return adopt_variant(development, confirmation, variants, "today")


def keep_the_net(judged: dict) -> bool:
    """Whether A+ replaces A by the criterion of "The moved members keep the shared gain's safety
    net" (module docstring) on :func:`judge_shared_ridge`'s figures: its share within 15 % on both
    not lower than A's, and its mean MAE ratio not higher than A's by more than one standard error
    of the per-scenario differences."""
    a, plus = (
        judged["A: always prior_shared_ridge"],
        judged["A+: prior_shared_ridge where today's rule offers prior_shared_gain"],
    )
    d = np.array(plus["mae_ratio"]) - np.array(a["mae_ratio"])
    se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else 0.0
    return bool(plus["share_both"] >= a["share_both"] and float(d.mean()) <= se + 1e-12)


def judge_shared(results: list[dict], added=SHARED) -> dict:
    """The shared adaptations judged (module docstring, "One shared adaptation"): for today's
    candidates (every candidate but :data:`JUDGED_SHARED`) and each of ``added`` (today's
    plus those), the product's CV pick per scenario, the share within 15 % on MAE, on worst and on
    both, the mean MAE ratio, and against today the mean and standard error of the per-scenario
    MAE ratio differences; ``adopted``: the criterion holds on ``results``."""

    def picks(extra: tuple) -> dict:
        out = {}
        for res in results:
            pool = {
                m: c
                for m, c in res["candidates"].items()
                if (m not in JUDGED_SHARED or m in extra) and m != SHARED_RIDGE
            }
            out[res["seed"]] = _lowest(pool, lambda c: c["selection_score_um"])
        return out

    def row(extra: tuple) -> dict:
        chosen = picks(extra)
        return ratio_row(chosen, [ratios(res, chosen[res["seed"]]) for res in results])

    today = row(())
    out = {"today": today}
    for name, extra in added.items():
        v = with_difference(row(tuple(extra)), today)
        v["adopted"] = bool(
            v["share_both"] > today["share_both"] and v["mean_mae_difference"] <= v["se_mae_difference"]
        )
        out[name] = v
    return out


def shared_markdown(judged: dict) -> str:
    """The shared adaptations' judgement: one row per candidate set, then the picks per scenario."""
    lines = [
        "| candidates | within 15 % on MAE | on worst | on both | mean MAE ratio | vs today: mean difference "
        "(SE) | criterion holds |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, v in judged.items():
        diff, held = difference_cells(v, "adopted")
        lines.append(
            f"| {name} | {100 * v['share_mae']:.0f} % | {100 * v['share_worst']:.0f} % "
            f"| {100 * v['share_both']:.0f} % | {v['mean_mae_ratio']:.3f} | {diff} | {held} |"
        )
    lines += ["", "| seed | " + " | ".join(f"{n}: pick, ratios MAE ; worst" for n in judged) + " |"]
    lines.append("|---|" + "---|" * len(judged))
    for seed in judged["today"]["picks"]:
        i = list(judged["today"]["picks"]).index(seed)
        cells = [
            f"{v['picks'][seed]} {v['mae_ratio'][i]:.2f} ; {v['worst_ratio'][i]:.2f}" for v in judged.values()
        ]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def no_fold_fit(seed: int, hours: float, args, settings: dict, prior_cache: dict) -> dict:
    """Random scenario ``seed`` with the plan with the prior for ``hours`` of new data (module
    docstring, "The no-fold default"): the fit with the prior, its selection basis (``default``:
    no CV fold) and pick, and every candidate's validation MAE and worst (the same validation runs
    as the full plan's)."""
    rs = random_scenario(seed)
    sc = rs.scenario(args.sample_period)
    prior, _, speeds, _ = fit_prior(rs.machine, args, settings, prior_cache)
    plan = plan_for(prior, speeds, hours, settings)
    data = combine(sc.plan_runs(plan), sc.new_validation())
    out = {"hours": float(hours), "plan_h": plan.attrs["total_h"], "speeds_rpm": plan.attrs["speeds_rpm"]}
    out["training_runs"] = int((data.table["role"] == "training").sum())
    out["prior_kind"] = str(prior.get("kind"))
    progress(f"seed {seed}: {hours:g} h ({out['training_runs']} training runs) with the prior")
    fit = fit_family(data, settings, sc.key_sensors, rs.machine, args.kinds, prior=prior)
    out["selection_basis"] = fit.get("selection_basis")
    out["champion"] = str(fit["champion"])
    out["candidates"] = every_candidate(fit)
    return out


def _no_fold_key(hours: float) -> str:
    return f"{float(hours):g}"


def judge_no_fold(results: list[dict], hours: float, defaults=NO_FOLD) -> dict:
    """The no-fold default judged (module docstring, "The no-fold default"), on the scenarios of
    ``results`` whose fit at ``hours`` has no CV fold (``left_out``: those with one): per default
    of ``defaults`` (a missing one - no shared gain for a prior of one kind - stands as
    ``defaults[0]``), its MAE and worst ratios to the full plan from scratch, the share within
    15 % on MAE, on worst and on both, the mean MAE ratio; for each default after the first, the
    mean and standard error of the per-scenario MAE ratio differences against the first, and
    ``adopted``: the share within 15 % on both not lower and the mean difference below minus one
    standard error."""
    key = _no_fold_key(hours)
    runs = [r for r in results if key in (r.get("no_fold") or {})]
    judged = [r for r in runs if r["no_fold"][key]["selection_basis"] == "default"]
    out = {
        "hours": float(hours),
        "seeds": [r["seed"] for r in judged],
        "left_out": [r["seed"] for r in runs if r not in judged],
        "product_picks": {r["seed"]: r["no_fold"][key]["champion"] for r in judged},
        "defaults": {},
    }
    for name in defaults:
        picks, r = {}, []
        for res in judged:
            cands = res["no_fold"][key]["candidates"]
            pick = name if name in cands else defaults[0]
            picks[res["seed"]] = pick
            r.append(ratios({**res, "candidates": cands}, pick))
        out["defaults"][name] = ratio_row(picks, r)
    base = out["defaults"][defaults[0]]
    for name in defaults[1:]:
        v = with_difference(out["defaults"][name], base)
        v["adopted"] = bool(
            v["share_both"] >= base["share_both"] and v["mean_mae_difference"] < -v["se_mae_difference"]
        )
    return out


def no_fold_markdown(judged: dict, results: list[dict]) -> str:
    """The no-fold defaults' judgement: one row per scenario (the product's pick, each default's
    ratios to the full plan), then one row per default."""
    names = list(judged["defaults"])
    changes = {r["seed"]: r.get("change", "") for r in results}
    lines = [
        f"No CV fold at {judged['hours']:g} h of new data (the plan with the prior): ratios to the full "
        "plan from scratch, MAE ; worst.",
        "",
        "| seed | change | product's pick | " + " | ".join(names) + " |",
        "|---|---|---|" + "---|" * len(names),
    ]
    for i, seed in enumerate(judged["seeds"]):
        cells = []
        for n in names:
            v = judged["defaults"][n]
            m, w = v["mae_ratio"][i], v["worst_ratio"][i]
            cells.append(f"{m:.2f} ; {w:.2f}{'' if passes(m, w) else ' (NO)'}")
        lines.append(
            f"| {seed} | {changes.get(seed, '')} | {judged['product_picks'][seed]} | "
            + " | ".join(cells)
            + " |"
        )
    lines += [
        "",
        "| default | within 15 % on MAE | on worst | on both | mean MAE ratio | vs "
        f"{names[0]}: mean difference (SE) | criterion holds |",
        "|---|---|---|---|---|---|---|",
    ]
    n = len(judged["seeds"])
    for name, v in judged["defaults"].items():
        diff, held = difference_cells(v, "adopted")
        lines.append(f"| {name} | {count_cells(v, n)} | {v['mean_mae_ratio']:.3f} | {diff} | {held} |")
    if judged["left_out"]:
        lines.append(
            f"\nLeft out (a CV fold at {judged['hours']:g} h): {', '.join(map(str, judged['left_out']))}."
        )
    return "\n".join(lines)


def run_random(seeds: list[int], args, settings: dict) -> list[dict]:
    """Every random scenario of ``seeds``; with ``--keep DIR`` each result is ``DIR/seed-<n>.json``,
    read back instead of run again (so a stopped run resumes)."""
    keep = Path(args.keep) if args.keep else None
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
    cache, out = {}, []
    for seed in seeds:
        path = keep / f"seed-{seed}.json" if keep is not None else None
        if path is not None and path.exists():
            res = json.loads(path.read_text())
            if float(res.get("budget_h", TARGET_HOURS)) != float(args.budget):
                raise SystemExit(
                    f"{path}: kept at {res.get('budget_h'):g} h of new data, asked for "
                    f"{args.budget:g} h (--budget): keep each budget in its own --keep DIR"
                )
            out.append(with_extras(res, path, args, settings, cache))
            continue
        started = time.perf_counter()
        res = one_random(seed, args, settings, cache)
        res["seconds"] = round(time.perf_counter() - started, 1)
        m, w = res["prior_mae_um"] / res["full_mae_um"], res["prior_um"] / res["full_um"]
        progress(
            f"seed {seed}: with the prior {both(res['prior_mae_um'], res['prior_um'])} um "
            f"({res['prior_choice']}), "
            f"full {both(res['full_mae_um'], res['full_um'])}: ratios {m:.2f} ; {w:.2f} "
            f"{'within' if passes(m, w) else 'NOT within'} 15 % ({res['seconds']:g} s)"
        )
        if path is not None:
            write_text_atomic(path, json.dumps(res, indent=1, default=float) + "\n")
        out.append(with_extras(res, path, args, settings, cache))
    return out


def with_extras(res: dict, path: Path | None, args, settings: dict, cache: dict) -> dict:
    """``res`` with what the options ask beside the 4 h fit: the fit without a fold
    (:func:`with_no_fold`) and the full plan run again (:func:`with_repeat_full`)."""
    return with_repeat_full(with_no_fold(res, path, args, settings, cache), path, args, settings)


def with_no_fold(res: dict, path: Path | None, args, settings: dict, cache: dict) -> dict:
    """``res`` with its fit at ``--no-fold-hours`` (:func:`no_fold_fit`) under ``no_fold``, fitted
    only when not kept yet (then written back to ``path``)."""
    hours = getattr(args, "no_fold_hours", None)
    if hours is None or _no_fold_key(hours) in (res.get("no_fold") or {}):
        return res
    res = {**res, "no_fold": {**(res.get("no_fold") or {})}}
    res["no_fold"][_no_fold_key(hours)] = no_fold_fit(res["seed"], hours, args, settings, cache)
    if path is not None:
        write_text_atomic(path, json.dumps(res, indent=1, default=float) + "\n")
    return res


def repeat_full(scenario, args, settings: dict) -> dict:
    """The full plan from scratch of ``scenario`` (a
    :class:`~rafi.twin.requalify_scenarios.RandomScenario`) run again on the same changed machine
    (:meth:`rafi.twin.scenarios.Scenario.new_full_training` with ``draw=1``: every run's noise and
    weather drawn afresh), judged on the same validation runs: the record's :data:`REPEAT_KEYS`
    and its champion's name."""
    sc = scenario.scenario(args.sample_period)
    progress(f"seed {scenario.seed}: the full plan from scratch again")
    fit = fit_family(
        combine(sc.new_full_training(draw=1), sc.new_validation()),
        settings,
        sc.key_sensors,
        sc.machine,
        args.kinds,
    )
    mae, worst, choice = champion_errors(fit)
    return {REPEAT_KEYS[0]: mae, REPEAT_KEYS[1]: worst, "repeat_full_choice": choice}


def with_repeat_full(res: dict, path: Path | None, args, settings: dict, scenario=None) -> dict:
    """``res`` with its second full plan from scratch (:func:`repeat_full` of ``scenario``, by
    default random scenario ``res["seed"]``) when ``--repeat-full`` asks for it and it is not kept
    yet (then written back to ``path``)."""
    if not getattr(args, "repeat_full", False) or all(k in res for k in REPEAT_KEYS):
        return res
    res = res | repeat_full(scenario or random_scenario(res["seed"]), args, settings)
    if path is not None:
        write_text_atomic(path, json.dumps(res, indent=1, default=float) + "\n")
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", action="append", choices=SCENARIOS, help="repeat; default: every one")
    p.add_argument(
        "--machine", default="tapping-center-a", choices=("tapping-center-a", "machining-center-b")
    )
    p.add_argument("--hours", type=float, nargs="+", default=list(HOURS))
    p.add_argument("--sample-period", type=float, default=20.0, help="s (default 20)")
    p.add_argument("--seed", type=int, default=0, help="the named scenarios' and the prior's seed")
    p.add_argument("--random", type=int, metavar="N", help="random scenarios of seeds 0..N-1")
    p.add_argument(
        "--budget",
        type=float,
        default=TARGET_HOURS,
        metavar="H",
        help=f"random scenarios: hours of new data with the prior (default {TARGET_HOURS:g}, the "
        "issue's target; other budgets say how far it is)",
    )
    p.add_argument(
        "--seeds", metavar="A-B", help="random scenarios of seeds A..B (with or instead of --random)"
    )
    p.add_argument(
        "--keep", metavar="DIR", help="one result JSON per random seed (and the priors) there; resumes"
    )
    p.add_argument(
        "--no-fold-hours",
        type=float,
        metavar="H",
        help="random scenarios: also fit H h of the plan with the prior (one run: no CV fold) and "
        "judge the no-fold default (prior_gain against prior_shared_gain)",
    )
    p.add_argument(
        "--repeat-full",
        action="store_true",
        help="random scenarios: also run each full plan from scratch a second time on the same "
        "machine (fresh noise and weather): how often the reference is within each tolerance of itself",
    )
    p.add_argument(
        "--issue-scenarios",
        action="store_true",
        help="the two scenarios issue 47 states (rafi.twin.requalify_scenarios.ISSUE_SCENARIOS), their "
        "new machine's runs seeded from --seeds (default 0-1), as the random ones",
    )
    p.add_argument(
        "--false-siblings",
        action="store_true",
        help="the random scenarios of --seeds (default 0-1) re-qualified from the other base machine's "
        "champion, declared a sibling: is the promotion stopped, and by which fitness warnings",
    )
    p.add_argument(
        "--other-designs",
        action="store_true",
        help="for each seed of --seeds (default 0-1) a random design's prior re-qualifies a true sibling "
        "of it and another design declared a sibling: stopped, by which warnings, and how far off",
    )
    p.add_argument("--kinds", nargs="+", help="the kinds run_family fits (default: models.enabled)")
    p.add_argument(
        "--offer",
        choices=("ensemble", "best"),
        help="models.offer of every qualification (default: the project's): `best` makes the prior a "
        "single kind, so the adaptations prior_gain / prior_time / prior_ridge are what is offered",
    )
    p.add_argument(
        "--plan-reference",
        choices=("run_start", "log_start"),
        default="run_start",
        help="random scenarios: the plan's recording referenced per run (the default reference.rule) "
        "or at the log's start (reference: {rule: log_start} for the fit with the prior)",
    )
    p.add_argument(
        "--json",
        default=str(ROOT / "benchmarks" / "results" / "requalify.json"),
        help="the record's path; its suffix becomes .json (default: benchmarks/results/requalify.json; "
        "random scenarios: requalify_random.json)",
    )
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    settings = MACHINE_DEFAULTS
    if args.offer is not None:
        settings = {**settings, "models": {**settings["models"], "offer": args.offer}}
    if not TAKES_PRIOR:
        progress("run_family has no 'prior' argument here: the 'with the prior' column stays empty")
    seeds = parse_seeds(args.random, args.seeds)
    if args.issue_scenarios:
        return main_issue(seeds or [0, 1], args, settings)
    if args.false_siblings:
        return main_false_siblings(seeds or [0, 1], args, settings)
    if args.other_designs:
        return main_other_designs(seeds or [0, 1], args, settings)
    if seeds:
        return main_random(seeds, args, settings)
    started, cache, results = time.perf_counter(), {}, []
    for name in args.scenario or SCENARIOS:
        results.append(one_scenario(name, args, settings, cache))
        progress(f"{name}: {verdict(results[-1])}")
    table = markdown(results)
    print(table)
    for res in results:
        print(f"\n{res['scenario']}: {verdict(res)}")
    record = {
        "machine": args.machine,
        "sample_period_s": args.sample_period,
        "seed": args.seed,
        "kinds": args.kinds or settings["models"]["enabled"],
        "takes_prior": TAKES_PRIOR,
        "seconds": round(time.perf_counter() - started, 1),
        "scenarios": results,
        "verdicts": {r["scenario"]: verdict(r) for r in results},
        "markdown": table,
    }
    out = Path(args.json)
    (written,) = write_results(
        out.stem, record, out_dir=out.parent, indent=1, default=float, final_newline=True
    )
    progress(f"wrote {written} ({record['seconds']:g} s)")
    return 0


def main_issue(seeds: list[int], args, settings: dict) -> int:
    """``--issue-scenarios``: issue 47's two scenarios at each seed, their table and record
    (``requalify_issue.json`` and ``.md`` unless ``--json``); nothing kept per seed."""
    started, cache = time.perf_counter(), {}
    results = []
    for name in ISSUE_SCENARIOS:
        for seed in seeds:
            scenario = issue_scenario(name, seed)
            res = one_random(seed, args, settings, cache, scenario=scenario)
            results.append(with_repeat_full(res, None, args, settings, scenario=scenario))
    return write_scenarios(random_markdown(results), results, seeds, started, args, "requalify_issue")


def write_scenarios(
    table: str, results: list[dict], seeds: list[int], started: float, args, stem: str
) -> int:
    """Print ``table`` and write it with the ``results`` of ``seeds`` as ``<stem>.md`` and
    ``.json`` (``--json``'s name and folder when given); nothing kept per seed."""
    print(table)
    out = Path(args.json)
    stem = out.stem if args.json != p_default_json() else stem
    record = {"seeds": seeds, "seconds": round(time.perf_counter() - started, 1), "scenarios": results}
    written = write_results(stem, record, table + "\n", out_dir=out.parent, indent=1, default=float)
    progress(f"wrote {', '.join(map(str, written))} ({record['seconds']:g} s)")
    return 0


def main_false_siblings(seeds: list[int], args, settings: dict) -> int:
    """``--false-siblings``: the random scenarios of ``seeds``, each re-qualified from the OTHER
    base machine's champion as if it were a declared sibling (the sensors and probe map match, so
    the origin check lets it through); their table and record (``requalify_false_siblings.json``
    and ``.md`` unless ``--json``); nothing kept per seed."""
    started, cache = time.perf_counter(), {}
    results = []
    for seed in seeds:
        machine = random_scenario(seed).machine
        results.append(one_random(seed, args, settings, cache, prior_machine=other_base(machine)))
    table = false_sibling_markdown(results)
    return write_scenarios(table, results, seeds, started, args, "requalify_false_siblings")


#: The base machine of the random designs of ``--other-designs`` (its sensor layout).
DESIGN_MACHINE = "tapping-center-a"


def fit_design_prior(seed: int, args, settings: dict, machine: str = DESIGN_MACHINE) -> tuple:
    """The prior of design ``seed`` (:func:`rafi.twin.requalify_scenarios.random_design`): its
    champion on its full test plan (the named scenarios' old machine with the design's constants),
    ``(artefact, champion, training speeds)``."""
    design = random_design(seed, machine)
    sc = Scenario(
        f"design-{seed}",
        machine,
        TwinMachine(design),
        TwinMachine(design),
        args.seed,
        args.sample_period,
        KEY_SENSORS[machine],
    )
    fit, speeds = qualify_old(sc, settings, args.kinds)
    return fit["best_artefact"], fit["champion"], speeds


def prior_misfit(res: dict) -> float:
    """The prior as it is on the new runs (the whole-run CV's ``prior`` score: the mean over
    held-out runs of the max |residual|) over the prior's own pooled 90 % half width: how many of
    its own intervals the prior lies off on this machine (NaN where a record lacks either)."""
    score = (res.get("candidates", {}).get("prior") or {}).get("selection_score_um", math.nan)
    return float(score) / float(res.get("prior_half_width_um", math.nan))


def other_design_markdown(results: list[dict]) -> str:
    """One row per re-qualification from a random design's prior, of a true sibling of the design
    or of another design declared a sibling (:func:`rafi.twin.requalify_scenarios.design_pair`);
    then, per kind, how many were stopped, by a warning on the prior (other than
    ``prior_speeds``), and within 15 % of the new machine's full plan on both."""
    h = f"{_budget_of(results):g} h"
    lines = [
        f"| design | re-qualified | CV chose | {h} with the design's prior, MAE ; worst (um) | ratio to the "
        "full plan from scratch, MAE ; worst | prior as it is / its own 90 % half width | fitness "
        "warnings | promotion stopped |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for res in results:
        lines.append(
            f"| {res['seed']} | {res['change']} | {res['prior_choice']} {_with_prior_cells(res)} "
            f"| {prior_misfit(res):.1f} {_stopped_cells(res)}"
        )
    lines.append("")
    for change, what in (("sibling", "true siblings"), ("other_design", "other designs declared siblings")):
        rs = [r for r in results if r["change"] == change]
        if not rs:
            continue
        stopped = sum(bool(r.get("warnings")) for r in rs)
        told = sum(_warned_on_prior(r) for r in rs)
        within = sum(_passes_as(r, "prior_mae_um", "prior_um") for r in rs)
        beyond = sum(prior_misfit(r) > MISFIT_HALF_WIDTHS for r in rs)
        lines.append(
            f"{what}: promotion stopped on {stopped} of {len(rs)}, by a warning on the prior (not "
            f"`{UNTESTED_SPEEDS}`) on {told}; within 15 % of the full plan on both: {within}; the prior "
            f"as it is beyond {MISFIT_HALF_WIDTHS:g} of its own half widths: {beyond}."
        )
    return "\n".join(lines)


def main_other_designs(seeds: list[int], args, settings: dict) -> int:
    """``--other-designs``: for each seed a random design's prior re-qualifies a true sibling of the
    design and another design declared a sibling; their table and record
    (``requalify_other_designs.json`` and ``.md`` unless ``--json``); nothing kept per seed."""
    started, results = time.perf_counter(), []
    for seed in seeds:
        progress(f"design {seed}: fitting its full qualification (the prior)")
        prior_fit = fit_design_prior(seed, args, settings)
        for scenario in design_pair(seed):
            results.append(one_random(seed, args, settings, {}, scenario=scenario, prior_fit=prior_fit))
    table = other_design_markdown(results)
    return write_scenarios(table, results, seeds, started, args, "requalify_other_designs")


def main_random(seeds: list[int], args, settings: dict) -> int:
    """``--random`` / ``--seeds``: every random scenario, its table, the rules judged, the record."""
    started = time.perf_counter()
    results = run_random(seeds, args, settings)
    table = random_markdown(results)
    judged = judge_rules(results)
    rules = rules_markdown(judged)
    shared = judge_shared(results)
    rules += "\n\n" + shared_markdown(shared)
    default = judge_default(results)
    rules += "\n\n" + default_markdown(default)
    shared_ridge = judge_shared_ridge(results)
    rules += "\n\n" + default_markdown(shared_ridge)
    no_fold = judge_no_fold(results, args.no_fold_hours) if args.no_fold_hours is not None else None
    no_fold_moved = None
    if no_fold is not None:
        rules += "\n\n" + no_fold_markdown(no_fold, results)
        no_fold_moved = judge_no_fold(results, args.no_fold_hours, defaults=NO_FOLD_MOVED)
        rules += "\n\n" + no_fold_markdown(no_fold_moved, results)
    print(table)
    print()
    print(rules)
    record = {
        "sample_period_s": args.sample_period,
        "prior_seed": args.seed,
        "seeds": seeds,
        "kinds": args.kinds or settings["models"]["enabled"],
        "seconds": round(time.perf_counter() - started, 1),
        "scenarios": results,
        "rules": judged,
        "shared": shared,
        "default": default,
        "shared_ridge": shared_ridge,
        "no_fold": no_fold,
        "no_fold_moved": no_fold_moved,
        "markdown": table + "\n\n" + rules,
    }
    out = Path(args.json)
    stem = out.stem if args.json != p_default_json() else "requalify_random"
    written = write_results(
        stem,
        record,
        record["markdown"] + "\n",
        out_dir=out.parent,
        indent=1,
        default=float,
        final_newline=True,
    )
    progress(f"wrote {', '.join(map(str, written))} ({record['seconds']:g} s)")
    return 0


def p_default_json() -> str:
    return str(ROOT / "benchmarks" / "results" / "requalify.json")


if __name__ == "__main__":
    sys.exit(main())
