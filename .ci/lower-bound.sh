#!/usr/bin/env bash
# The lower bound of the supported Snakemake range (pyproject.toml: "snakemake>=X,<Y"):
# a fresh venv with exactly snakemake==X runs the nightly tests end to end, so the API and the
# structured log records `rafi nightly` relies on (rafi/ops/snakemake_api.py) work there too.
#   .ci/lower-bound.sh            # venv in ${RAFI_LOWER_VENV:-/tmp/rafi-snakemake-lower}
set -euo pipefail
cd "$(dirname "$0")/.."
lower=$(sed -n 's/^ *"snakemake>=\([0-9][0-9.]*\),.*/\1/p' pyproject.toml)
if [ -z "$lower" ]; then
    echo "lower-bound.sh: no \"snakemake>=X,...\" line in pyproject.toml" >&2
    exit 2
fi
venv=${RAFI_LOWER_VENV:-/tmp/rafi-snakemake-lower}
python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q -e '.[test]' "snakemake==$lower"
"$venv/bin/python" -c "import snakemake, sys; v = snakemake.__version__; print('snakemake', v); sys.exit(v != '$lower')"
PATH="$venv/bin:$PATH" "$venv/bin/python" -m pytest -q -p no:cacheprovider tests/test_nightly.py
