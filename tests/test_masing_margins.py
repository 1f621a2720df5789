"""Eq. 4 / Eq. 6 margins converge as the sampling is refined (issue 14).

Seed Fig. 3(e)-(f) (models/seed_fig3/sin2.toml) with the physical (anchor)
law: u = sin(2 pi t), N = 5 + sin(4 pi t), mu = 0.1, kt = 1, three periods from
rest, the last one checked.  The pointwise margin used to grow with the
sample count (-15.3, -64.2, -260, -1042); the integrated one converges.
"""
import numpy as np

from jointsim.contact.select import tangential_law
from jointsim.masing import check_loops
from jointsim.scene import Joint, load_scene


def sin2_report(n):
    sc = load_scene("models/seed_fig3/sin2.toml")
    j = sc.joint
    law = tangential_law(j.law, "anchor", Joint(law=j.law, reversal="anchor", mu=j.mu, kt=j.kt),
                         [1.0])
    t = np.arange(3 * n) / n
    u = np.sin(2 * np.pi * t)
    N = 5.0 + np.sin(4 * np.pi * t)
    f = law.march(u[None], N[None], law.rest_state([N[0]]))[0]
    return check_loops(u[None, -n:], f[:, -n:], N[None, -n:], law)


def test_eq4_margin_converges_and_keeps_its_verdict():
    reps = [sin2_report(n) for n in (256, 1024, 4096, 16384)]
    m4 = np.array([r.eq4_margin[0] for r in reps])
    m6 = np.array([r.eq6_margin[0] for r in reps])
    assert all(not r.eq4_ok[0] for r in reps) and (m4 < 0).all()      # violated, robustly
    assert all(r.eq6_ok[0] for r in reps) and (m6 > 0).all()
    assert abs(m4[-1] - m4[-2]) < 0.05 * abs(m4[-1])
    assert abs(m6[-1] - m6[-2]) < 0.05 * abs(m6[-1])
    assert m4[-1] < -1e-3
