"""Units: SI inside, user units at the edges.

Every quantity inside cardiosoft is SI (m, m^3, Pa, N, s, J). A user unit is the SI value of one
of it, so multiplying converts *to* SI and dividing converts *from* SI::

    from cardiosoft.units import mmHg, ml, mm
    p = 90 * mmHg      # Pa
    v_ml = v / ml      # a volume in m^3 read in ml
"""

import math

mm = 1e-3
"""One millimetre in m."""
cm = 1e-2
"""One centimetre in m."""
ml = 1e-6
"""One millilitre in m^3."""
mmHg = 133.322387415
"""One millimetre of mercury in Pa (conventional, 13.5951 g/cm^3 at g = 9.80665 m/s^2)."""
N = 1.0
"""One newton (already SI; named so that printed tables read ``F / N``)."""
J = 1.0
"""One joule."""
s = 1.0
"""One second."""
minute = 60.0
"""One minute in s."""
l_per_min = 1e-3 / minute
"""One litre per minute in m^3/s (a cardiac output, a mean flow)."""
bpm = 1.0 / 60.0
"""One beat per minute in Hz: ``60 * bpm`` is 1 Hz and the period is ``1 / (60 * bpm)`` s."""
deg = math.pi / 180.0
"""One degree in rad."""

mmHg_s_per_ml = mmHg / ml
"""Resistance unit: 1 mmHg s/ml in Pa s/m^3."""
ml_per_mmHg = ml / mmHg
"""Compliance unit: 1 ml/mmHg in m^3/Pa."""
mmHg_s2_per_ml = mmHg / ml
"""Inertance unit: 1 mmHg s^2/ml in Pa s^2/m^3."""

RHO_WATER = 998.0
"""Density of water at about 20 C, kg/m^3."""
MU_WATER = 1.0e-3
"""Dynamic viscosity of water at about 20 C, Pa s."""
G = 9.80665
"""Standard gravity, m/s^2."""
