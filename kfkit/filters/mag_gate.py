"""The MEKF's magnetometer gate: is this magnetometer sample to be used (norm and dip gates,
innovation gate, bounded rejection that adopts a field that changed for good)?"""

from __future__ import annotations

import math

from ..frames import wrap_angle_f


class MagGate:
    """Whether to use each magnetometer sample: the MEKF's magnetic-disturbance logic in three layers
    (see :class:`kfkit.filters.mekf.MultiplicativeEKF`), one sample at a time. Its reference field and
    clocks carry from one sample (and one run) to the next.

    field_n     reference field, NED (µT): the starting reference norm ‖m‖ and dip atan2(m_D, ‖m_h‖)
    settings    the MEKF's settings (:class:`~kfkit.filters.mekf.MultiplicativeEKFSettings`): its gates
                ``mag_norm_gate`` (a fraction of the reference norm) and ``mag_dip_gate`` (rad), None = off;
                ``mag_recovery`` (s the field must pass the gates after a rejection before it is used again;
                also the averaging time and the duration of the innovation tests); ``mag_nis_gate`` (χ², 1 dof,
                of the innovation tests; None = none: a disturbed field is rejected for as long as it fails the
                gates); ``mag_ref_tau`` (s with which the reference follows a trusted field; None = fixed)

    The gates test the field's norm and dip low-passed with a time constant of CURRENT_TAU = 0.05 s (VQF's
    magCurrentTau), so that their verdict on a steady field does not depend on the sample rate (the noise of
    one sample does).
    """

    CURRENT_TAU = 0.05

    __slots__ = (
        "norm_ref",
        "dip_ref",
        "norm_gate",
        "dip_gate",
        "recovery",
        "nis_gate",
        "ref_rate",
        "good_since",
        "t_prev",
        "nis_since",
        "mean",
        "adopt_since",
        "current",
    )

    def __init__(self, field_n, settings):
        mN, mE, mD = (float(v) for v in field_n)
        self.norm_ref, self.dip_ref = math.sqrt(mN * mN + mE * mE + mD * mD), math.atan2(mD, math.hypot(mN, mE))
        st = settings
        self.norm_gate = st.mag_norm_gate if st.mag_norm_gate is not None else math.inf  # fraction of norm_ref
        self.dip_gate = st.mag_dip_gate if st.mag_dip_gate is not None else math.inf
        self.recovery = st.mag_recovery
        self.nis_gate = st.mag_nis_gate if st.mag_nis_gate is not None else math.inf
        self.ref_rate = 1.0 / st.mag_ref_tau if st.mag_ref_tau else 0.0
        self.good_since = -math.inf  # time since which the field has passed the gates (trusted from the start)
        self.t_prev = None  # time of the previous magnetometer sample
        self.nis_since = None  # first of the trusted samples in a row that failed the innovation gate
        self.mean = None  # while disturbed: averaged [heading innovation, its noise variance, norm, dip]
        self.adopt_since = None  # since when the disturbed field's averaged heading agrees with the filter's
        self.current = None  # [norm, dip] low-passed with CURRENT_TAU

    def use(self, t, norm, dip, y, var_h, r_psi):
        """True if the sample at time t (s) is to be used: field norm (µT) and dip (rad) seen with the
        current attitude, heading innovation y (rad), the filter's heading variance var_h = H P Hᵀ (rad²) and
        the sample's own heading variance r_psi (rad²)."""
        dt_m = t - self.t_prev if self.t_prev is not None else 0.0
        self.t_prev = t
        if self.current is None:
            self.current = [norm, dip]
        else:
            a = 1.0 - math.exp(-dt_m / self.CURRENT_TAU)
            self.current[0] += a * (norm - self.current[0])
            self.current[1] += a * (dip - self.current[1])
        norm, dip = self.current
        if abs(norm - self.norm_ref) > self.norm_gate * self.norm_ref or abs(dip - self.dip_ref) > self.dip_gate:
            self.good_since = math.inf
        elif self.good_since > t:
            self.good_since = t
        if t - self.good_since >= self.recovery:  # trusted
            self.mean = None
            if self.ref_rate:  # the reference follows a trusted field slowly
                a = min(1.0, dt_m * self.ref_rate)
                self.norm_ref += a * (norm - self.norm_ref)
                self.dip_ref += a * (dip - self.dip_ref)
            if y * y <= self.nis_gate * (var_h + r_psi):
                self.nis_since = None
                return True
            if self.nis_since is None:
                self.nis_since = t
            return t - self.nis_since >= self.recovery  # an outlier, unless it has lasted
        self.nis_since = None
        if self.nis_gate == math.inf:
            return False
        # disturbed: average its heading innovation, norm and dip; v = variance of the averaged noise
        if self.mean is None:
            self.mean, self.adopt_since = [y, r_psi, norm, dip], None
        else:
            a = 1.0 - math.exp(-dt_m / self.recovery)
            m = self.mean
            m[0] += a * wrap_angle_f(y - m[0])
            m[1] = (1.0 - a) ** 2 * m[1] + a * a * r_psi
            m[2] += a * (norm - m[2])
            m[3] += a * (dip - m[3])
        y_mean, v_mean, norm_mean, dip_mean = self.mean
        if v_mean <= var_h and y_mean * y_mean <= self.nis_gate * (var_h + v_mean):
            if self.adopt_since is None:
                self.adopt_since = t
            if t - self.adopt_since >= self.recovery:  # agrees in heading: the field changed for good
                self.norm_ref, self.dip_ref = norm_mean, dip_mean
                self.good_since, self.mean = t - self.recovery, None
                return True
        else:
            self.adopt_since = None
        return False
