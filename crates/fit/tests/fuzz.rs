//! Fuzzing: random windows (sizes, values with NaN/inf/huge/negative, masks, saturation,
//! starts) never panic and never give an unflagged NaN, for every estimator and solver.

use bostrack_core::{DotFlags, NoiseModel, Window};
use bostrack_fit::{Estimator, FitConfig, FitSampling, Fitter, Solver, WindowSamples};
use bostrack_model::ModelKind;
use proptest::prelude::*;

fn value() -> impl Strategy<Value = f64> {
    prop_oneof![
        8 => -50.0f64..5000.0,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1e300),
        1 => Just(1e300),
        1 => Just(0.0),
    ]
}

fn window_values() -> impl Strategy<Value = (usize, usize, Vec<f64>)> {
    (1usize..14, 1usize..14)
        .prop_flat_map(|(w, h)| (Just(w), Just(h), prop::collection::vec(value(), w * h)))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    #[test]
    fn random_windows_never_panic_or_hide_nan(
        (w, h, values) in window_values(),
        sx in -5.0f64..20.0, sy in -5.0f64..20.0,
        est in 0usize..4, model in 0usize..3, point in any::<bool>(),
        sat in prop::option::of(100.0f64..6000.0),
        mask_every in 0usize..5,
        read in prop_oneof![Just(0.0f64), 0.1f64..50.0], gain in 0.0f64..2.0,
    ) {
        let (estimator, solver) = match est {
            0 => (Estimator::Lsg, Solver::Fast),
            1 => (Estimator::Lsg, Solver::LmCrate),
            2 => (Estimator::Iwc, Solver::Fast),
            _ => (Estimator::Tpg, Solver::Fast),
        };
        let cfg = FitConfig {
            estimator,
            solver,
            model: [ModelKind::Elliptical, ModelKind::AxisAligned, ModelKind::Circular][model],
            sampling: if point { FitSampling::Point } else { FitSampling::Integrated },
            ..Default::default()
        };
        let keep: Vec<bool> = (0..w * h).map(|k| mask_every == 0 || k % (mask_every + 1) != 0).collect();
        let s = WindowSamples { window: Window::new(-3, 7, w, h), values: &values, keep: Some(&keep), saturation: sat };
        let noise = NoiseModel { read_variance: read * read, gain, offset: 10.0 };
        let f = Fitter::new(&cfg).fit_samples(&s, [sx - 3.0, sy + 7.0], None, &noise);
        let p = f.params;
        let pos = [p.x0, p.y0];
        if f.status.is_ok() {
            prop_assert!(pos.iter().all(|v| v.is_finite()), "{f:?}");
            prop_assert!(!f.flags.contains(DotFlags::FIT_FAILED));
            if estimator == Estimator::Lsg {
                prop_assert!(p.is_valid(), "{f:?}");
                prop_assert!(s.window.contains_point(p.x0, p.y0), "{f:?}");
            }
        } else {
            prop_assert!(f.flags.contains(DotFlags::FIT_FAILED), "{f:?}");
        }
    }
}
