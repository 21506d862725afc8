"""Hard-case stability suite: pass/fail checks on scenes that break weak solvers.

Every case is a function ``case(*, out_dir=None, log=None, **settings) ->
CaseResult``; keyword settings override the case's defaults (``DEFAULTS``), so
the tests can run small versions (fewer boxes, shorter time) and deliberately
broken ones (soft contact, no contact, an integrator that gains energy). All
cases use impulse contact (where there is contact) at dt = 1/60 s in float64
unless told otherwise. ``build`` settings go to ``Scene.build`` on top of the
case's own.

The cases (issue 6, item 3); each module's docstring gives its cases' scenes,
criteria and measured values:

1. :func:`tallest_stack`: the tallest 3D column of boxes that stands 10 s.
2. :func:`pyramid_2d`: a 2D pyramid of 20 rows standing 10 s.
3. :func:`mass_ratio`: light–heavy–light 3D columns, r = 100 and 1 000.
4. :func:`impact`: a sphere and a box thrown down at up to 1 000 m/s, with
   and without time of impact: the fastest speed that does not tunnel.
5. :func:`spin`: no energy gain spinning at 100 rad/s about the intermediate axis.
6. :func:`overlap_recovery`: a 2D pyramid started with 25 % overlaps
   separates, its kinetic energy bounded.
7. :func:`long_rest`: a resting 3-box column for 10⁵ steps: no NaN, no drift.

The package's modules (use the names from ``jaxrb.bench.hard_cases``; each
module imports only those listed before it):

* ``common``: the boxes' constants, :data:`DEFAULTS` / :data:`FULL` /
  :data:`QUICK`, :class:`CaseResult`, settings merge and figure saving;
* ``chunks``: :func:`simulate`, compiled rollouts in chunks cached per
  Model, and their :class:`Trace`;
* ``stacks``: cases 1–3 and 7, and the "stands" criterion
  (:func:`standing_figures`, :func:`stands`);
* ``impacts``: cases 4 and 6;
* ``spinning``: case 5;
* ``section``: :data:`CASE_FUNCTIONS`, the table (:func:`markdown`) and
  :func:`hard_cases_section`.
"""

from jaxrb.bench.hard_cases.chunks import Trace, simulate
from jaxrb.bench.hard_cases.common import (BOX_MASS, CASES, DEFAULTS, DT, FRICTION, FULL, HALF, QUICK,
                                           CaseResult)
from jaxrb.bench.hard_cases.impacts import (REST_TOL, impact, impact_scene, overlap_recovery,
                                            overlapped_pyramid_scene)
from jaxrb.bench.hard_cases.section import CASE_FUNCTIONS, hard_cases_section, markdown
from jaxrb.bench.hard_cases.spinning import SPIN_INERTIA, spin, spin_energy
from jaxrb.bench.hard_cases.stacks import (COLLAPSE_TOL, DRIFT_TOL, PENETRATION_TOL, SPEED_TOL,
                                           STANDS_TEXT, long_rest, mass_ratio, pyramid_2d,
                                           standing_figures, stands, tallest_stack)

__all__ = [
    # common
    "HALF", "BOX_MASS", "FRICTION", "DT", "DEFAULTS", "CASES", "FULL", "QUICK", "CaseResult",
    # chunks
    "Trace", "simulate",
    # stacks
    "DRIFT_TOL", "PENETRATION_TOL", "SPEED_TOL", "COLLAPSE_TOL", "STANDS_TEXT", "standing_figures",
    "stands", "tallest_stack", "pyramid_2d", "mass_ratio", "long_rest",
    # impacts
    "REST_TOL", "overlapped_pyramid_scene", "impact_scene", "impact", "overlap_recovery",
    # spinning
    "SPIN_INERTIA", "spin_energy", "spin",
    # section
    "CASE_FUNCTIONS", "markdown", "hard_cases_section",
]
