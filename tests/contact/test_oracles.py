"""Contact laws against the analytic oracles of DESIGN §5."""
import numpy as np
import pytest

from jointsim.contact import iwan4_constants, tangential_law
from jointsim.scene import Joint
from jointsim.solvers.prescribed import march_prescribed

from .. import _reference as ref


def march_cos(law, A, N, ns, n_periods=3):
    """Last steady period of u = A cos(theta) (theta = 2 pi k / ns) from rest."""
    theta = 2 * np.pi * np.arange(n_periods * ns) / ns
    u = A * np.cos(theta)[None, :]
    # start from rest: u(0) = A, so prepend nothing; the rest state is at u = 0 and
    # the first sample loads the element to u = A, as a virgin loading
    Nt = np.broadcast_to(np.atleast_2d(N), u.shape) if np.ndim(N) > 1 else np.full(u.shape, N)
    res = march_prescribed(u, Nt, law, ns, 1.0)
    assert res.convergence.success, res.convergence.message
    u1, f1, N1 = res.last_period()
    return theta[:ns], u1[0], f1[0], N1[0]


def dft_first(theta, f):
    ns = f.size
    return 2.0 / ns * np.sum(f * np.cos(theta)), 2.0 / ns * np.sum(f * np.sin(theta))


def jenkins(kt=1.0, mu=0.1, reversal="anchor"):
    j = Joint(law="jenkins", reversal=reversal, mu=mu, kt=kt)
    return tangential_law("jenkins", reversal, j, [1.0])


def _jenkins_dft_error(law, A, N, ns, exact):
    theta, u, f, _ = march_cos(law, A, N, ns)
    c1, s1 = dft_first(theta, f)
    D = -np.pi * A * s1  # work per cycle: -A * integral(f sin theta) = -pi A s1
    return max(abs(c1 / exact[0] - 1), abs(s1 / exact[1] - 1), abs(D / exact[2] - 1))


def test_jenkins_first_harmonic_and_dissipation():
    """c1, s1 and D by DFT of a marched loop: 1e-5 relative at 1024, ~2nd order.

    The march is exact at the samples (rate independence); the error is the
    quadrature of a loop whose slope jumps at the slip onset.  Where the kink
    falls between samples changes from one sample count to the next, so the
    order is fitted to the worst error in each octave of sample counts.
    """
    A, kt, N, mu = 1.0, 1.0, 3.0, 0.1
    exact = ref.jenkins_describing(A, kt, mu * N)
    law = jenkins(kt, mu)
    assert _jenkins_dft_error(law, A, N, 1024, exact) < 1e-5
    octaves = 2 ** np.arange(6, 12)
    worst = []
    for base in octaves:
        counts = np.unique((base * 2 ** (np.arange(6) / 6)).astype(int) // 2 * 2)
        worst.append(max(_jenkins_dft_error(law, A, N, int(n), exact) for n in counts))
    slope = np.polyfit(np.log(octaves), np.log(worst), 1)[0]
    assert -2.4 < slope < -1.5, f"convergence order {-slope:.2f}, expected about 2"


def test_jenkins_dissipation_by_loop_area():
    """Trapezoidal area of the marched loop: exact on the straight stick and slip
    segments, off only on the two segments holding a slip onset, each by less
    than kt du^2 with du <= A 2 pi / ns."""
    A, kt, N, mu, ns = 2.0, 1.5, 4.0, 0.2, 2048
    _, u, f, _ = march_cos(jenkins(kt, mu), A, N, ns)
    bound = 2 * kt * (A * 2 * np.pi / ns) ** 2
    D_ex = ref.jenkins_describing(A, kt, mu * N)[2]
    assert abs(ref.loop_dissipation(u, f) - D_ex) < bound


@pytest.mark.parametrize("chi,beta", [(-0.5, 0.1), (-0.2, 1.0)])
def test_iwan4_microslip_dissipation(chi, beta):
    """D = 4 R A^(chi+3) / ((chi+2)(chi+3)) for A < phi_max.

    With n sliders on [0, phi_max] the bin width is h = phi_max/(n-1); the loop
    integral then has a quadrature error from the bin that straddles A, of order
    (h/A)^2 relative.  The test asks for 2 (h/A)^2 and checks that the error
    falls at about that rate when n doubles.
    """
    KT, mu, N = 2.0, 0.1, 5.0
    Fs = mu * N
    c, phimax, R, S = iwan4_constants(KT, Fs, chi, beta)
    A = 0.6 * phimax
    D_ex = 4 * R * A ** (chi + 3) / ((chi + 2) * (chi + 3))
    errs = []
    ns_list = [100, 200, 400]
    for n in ns_list:
        j = Joint(law="iwan4", mu=mu, kt=KT, chi=chi, beta=beta, n_sliders=n,
                  iwan_spacing="uniform")
        law = tangential_law("iwan4", "anchor", j, [1.0])
        _, u, f, _ = march_cos(law, A, N, 4096)
        D = ref.loop_dissipation(u, f)
        h = phimax / (n - 1)
        err = abs(D / D_ex - 1)
        assert err < 2 * (h / A) ** 2, (n, err, (h / A) ** 2)
        errs.append(err)
    rate = np.polyfit(np.log(ns_list), np.log(errs), 1)[0]
    assert rate < -1.5, f"error falls as n^{rate:.2f}, expected about n^-2"


@pytest.mark.parametrize("law_name", ["jenkins", "iwan4"])
def test_masing_dissipation_formula(law_name):
    """Marched loop area equals 8 int_0^A f_bb - 4 A f_bb(A) at constant N."""
    j = Joint(law=law_name, mu=0.15, kt=2.0, chi=-0.3, beta=0.5, n_sliders=30)
    law = tangential_law(law_name, "anchor", j, [1.0])
    A, N = 0.7, 2.0
    _, u, f, _ = march_cos(law, A, N, 4096)
    x = np.linspace(0, A, 200001)
    fbb = law.backbone(x[None, :], np.full((1, x.size), N))[0]
    integral = np.sum(0.5 * (fbb[1:] + fbb[:-1]) * np.diff(x))
    D_masing = 8 * integral - 4 * A * fbb[-1]
    assert ref.loop_dissipation(u, f) == pytest.approx(D_masing, rel=1e-6)


def test_rigid_slip_dissipation_with_harmonic_normal_load():
    """D = mu A (4 N0 - (4/3) N2 cos psi) for rigid slip (kt -> infinity)."""
    A, mu, N0, N1, N2, psi1, psi = 0.5, 0.3, 2.0, 0.7, 0.9, 0.4, 1.1
    ns = 20000
    theta = 2 * np.pi * np.arange(3 * ns) / ns
    N = N0 + N1 * np.cos(theta + psi1) + N2 * np.cos(2 * theta + psi)
    u = A * np.cos(theta)
    law = jenkins(kt=1e9, mu=mu)
    res = march_prescribed(u[None, :], N[None, :], law, ns, 1.0)
    u1, f1, _ = res.last_period()
    D = ref.loop_dissipation(u1[0], f1[0])
    D_ex = mu * A * (4 * N0 - 4.0 / 3.0 * N2 * np.cos(psi))
    # errors: stuck arcs of length mu N / kt ~ 1e-9 and O((2 pi/ns)^2) quadrature
    assert D == pytest.approx(D_ex, rel=2e-7)


@pytest.mark.parametrize("chi", [-0.5, -0.2, 0.3])
def test_iwan_default_discretisation_dissipation_within_one_percent(chi):
    """The default Iwan element (geometric bins, count from joint.iwan_rtol = 1 %):
    marched loops dissipate within 1 % of Segalman's closed form from
    0.01 phi_max to phi_max (microslip), and within 1 % in macroslip where the
    spike adds 4 S phi_max (A - phi_max)."""
    beta, KT, mu, N = 0.2, 2.0, 0.1, 5.0
    Fs = mu * N
    c, phimax, R, S = iwan4_constants(KT, Fs, chi, beta)
    law = tangential_law("iwan4", "anchor", Joint(law="iwan4", mu=mu, kt=KT, chi=chi,
                                                  beta=beta), [1.0])
    assert law.n_sliders <= 80
    for a in np.geomspace(0.01, 1.0, 9).tolist() + [1.5, 3.0]:
        A = a * phimax
        _, u, f, _ = march_cos(law, A, N, 8192)
        D = ref.loop_dissipation(u, f)
        micro = 4 * R * min(A, phimax) ** (chi + 3) / ((chi + 2) * (chi + 3))
        if A > phimax:   # the power-law sliders all slip, plus the spike
            micro = 4 * (Fs - S * phimax) * A - 4 * R * phimax ** (chi + 3) / (chi + 3) \
                + 4 * S * phimax * (A - phimax)
        assert abs(D / micro - 1) < 0.01, (chi, a, D / micro - 1)
