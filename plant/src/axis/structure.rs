//! The linear structure of an axis in motor units: what the exact matrices are built from.

use nalgebra::DMatrix;

use feedloop_model::model::PlantParams;

use crate::effects::{current_lag, third_mass, EffectSet, Viscous};
use crate::linear::NU;

/// Linear structure of an axis in motor units (what the matrices are built from).
#[derive(Debug, Clone, Copy)]
pub(super) struct Structure {
    pub(super) two_mass: bool,
    pub(super) n: usize,
    /// Motor inertia (kg m^2) or rigid mass (kg).
    pub(super) jm: f64,
    pub(super) dm: f64,
    pub(super) kl: f64,
    pub(super) cl: f64,
    pub(super) jl: f64,
    pub(super) dl: f64,
    /// Third mass: (index of its position, inertia, stiffness, damping).
    pub(super) third: Option<(usize, f64, f64, f64)>,
    /// Current lag: (state index, tau_s).
    pub(super) lag: Option<(usize, f64)>,
}

impl Structure {
    pub(super) fn load_idx(&self) -> (usize, usize) {
        if self.two_mass {
            (2, 3)
        } else {
            (0, 1)
        }
    }

    /// Continuous `(A, B)` with the transmission spring engaged or not.
    pub(super) fn continuous(&self, spring_on: bool) -> (DMatrix<f64>, DMatrix<f64>) {
        let n = self.n;
        let mut a = DMatrix::<f64>::zeros(n, n);
        let mut b = DMatrix::<f64>::zeros(n, NU);
        let (lp, lv) = self.load_idx();
        let jload = if self.two_mass { self.jl } else { self.jm };
        a[(0, 1)] = 1.0;
        a[(1, 1)] = -self.dm / self.jm;
        b[(1, 1)] = 1.0 / self.jm;
        if self.two_mass {
            a[(2, 3)] = 1.0;
            a[(3, 3)] = -self.dl / self.jl;
            b[(3, 2)] = 1.0 / self.jl;
            if spring_on {
                let (k, c) = (self.kl, self.cl);
                a[(1, 0)] -= k / self.jm;
                a[(1, 2)] += k / self.jm;
                a[(1, 1)] -= c / self.jm;
                a[(1, 3)] += c / self.jm;
                a[(3, 0)] += k / self.jl;
                a[(3, 2)] -= k / self.jl;
                a[(3, 1)] += c / self.jl;
                a[(3, 3)] -= c / self.jl;
            }
        } else {
            b[(1, 2)] = 1.0 / self.jm;
        }
        if let Some(t) = self.third {
            third_mass::stamp(&mut a, (lp, lv), jload, t);
        }
        match self.lag {
            Some((il, tau)) => current_lag::stamp(&mut a, &mut b, il, tau, self.jm),
            None => b[(1, 0)] = 1.0 / self.jm,
        }
        (a, b)
    }

    /// Upper bound of the highest undamped natural frequency, rad/s (Gershgorin bound of the
    /// mass-normalised stiffness matrix).
    pub(super) fn omega_max(&self) -> f64 {
        let mut masses = Vec::new();
        let mut springs = Vec::new();
        if self.two_mass {
            masses.extend([self.jm, self.jl]);
            springs.push((0, 1, self.kl));
        } else {
            masses.push(self.jm);
        }
        if let Some((_, j3, k3, _)) = self.third {
            let attach = masses.len() - 1;
            masses.push(j3);
            springs.push((attach, attach + 1, k3));
        }
        let m = masses.len();
        let mut k = vec![0.0; m * m];
        for &(i, j, s) in &springs {
            k[i * m + i] += s;
            k[j * m + j] += s;
            k[i * m + j] -= s;
            k[j * m + i] -= s;
        }
        let mut w2: f64 = 0.0;
        for i in 0..m {
            let row: f64 = (0..m)
                .map(|j| k[i * m + j].abs() / (masses[i] * masses[j]).sqrt())
                .sum();
            w2 = w2.max(row);
        }
        w2.sqrt()
    }
}

impl Structure {
    /// The structure of a model's plant, with the effects' mean viscous parts, third mass and
    /// current lag.
    pub(super) fn of(plant: &PlantParams, fx: &EffectSet) -> Self {
        let mut st = match *plant {
            PlantParams::BallScrew { two_mass, .. } | PlantParams::Rotary { two_mass, .. } => {
                Structure {
                    two_mass: true,
                    n: 4,
                    jm: two_mass.jm_kgm2,
                    dm: two_mass.dm_nms_per_rad + Viscous::mean(fx.viscous[0]),
                    kl: two_mass.kl_nm_per_rad,
                    cl: two_mass.cl_nms_per_rad,
                    jl: two_mass.jl_kgm2,
                    dl: two_mass.dl_nms_per_rad + Viscous::mean(fx.viscous[1]),
                    third: None,
                    lag: None,
                }
            }
            PlantParams::Rigid(r) => Structure {
                two_mass: false,
                n: 2,
                jm: r.mass_kg,
                dm: r.viscous_ns_per_m + Viscous::mean(fx.viscous[0]),
                kl: 0.0,
                cl: 0.0,
                jl: 0.0,
                dl: 0.0,
                third: None,
                lag: None,
            },
        };
        if let Some(t) = fx.third_mass {
            st.third = Some((st.n, t.inertia, t.stiffness, t.damping));
            st.n += 2;
        }
        if let Some(tau) = fx.lag_tau_s {
            st.lag = Some((st.n, tau));
            st.n += 1;
        }
        st
    }
}
