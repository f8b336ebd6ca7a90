"""The seed paper's claims, checked: the functions behind `grazejax reproduce`.

Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*. `compute_claims` computes
rows of the claims table (one row per numeric or qualitative claim: the value printed in the
paper, grazejax's value, an independent check and a verdict with its reason); see
[the paper audit](audit.md) for what a row holds. The notebook
`notebooks/02-paper-walkthrough.ipynb` calls it group by group.

The subpackage's modules: `runs` (the batched, chunked simulations), `figures` (with one
`figures_*` module per example), `table` (printed values, facts, verdicts), `claims` (with
one `claims_*` module per example), `report` (report.md and report.json) and `reproduce`
(what `grazejax reproduce` runs).

**Example:**

```python
from grazejax.paper import CLAIM_GROUPS, compute_claims

print(list(CLAIM_GROUPS))                    # the groups, cheapest first within an example
table = compute_claims(["smalldisc"])        # a few seconds; all groups: 2-3 minutes
for row in table["rows"]:
    print(row["id"], row["verdict"], row["reason"])
```
"""

from .claims import CLAIM_GROUPS as CLAIM_GROUPS
from .claims import compute_claims as compute_claims
from .table import CLAIM_TOL as CLAIM_TOL

__all__ = ["CLAIM_GROUPS", "CLAIM_TOL", "compute_claims"]
