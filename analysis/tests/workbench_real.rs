//! The workbench on real records of machines nobody here made (issue 30): the EMPS benchmark and
//! three joints of a KUKA KR300 robot (data of Weigand et al., JonasWeigand/Robot_Identification,
//! MIT licence; see `../shared/data/kuka/README.md`). Never silently wrong: a requested effect is
//! fitted or refused with its reason, and every effect of the library is either ranked or listed
//! as untested with a reason. Each test is skipped, with a message, when its data are absent.

use std::path::{Path, PathBuf};

use feedloop_analysis::workbench::{
    data::{load_axis, AxisData, Prep},
    diagnose::{diagnose, DiagOptions},
    effects::WbModel,
    fit::fit,
    WorkbenchError,
};
use feedloop_model::EffectId;
use feedloop_trace::Trace;

fn shared(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipped: {} is absent", p.display());
        None
    }
}

fn emps() -> Option<(WbModel, AxisData)> {
    let tr = Trace::read(&shared("emps/emps_estimation.csv")?).unwrap();
    let m = WbModel::load(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/models/emps-nominal.toml"),
    )
    .unwrap();
    let d = load_axis(&tr, &m.file, "x", &Prep::default()).unwrap();
    Some((m, d))
}

/// Every effect of the library is ranked or untested with a reason.
fn assert_no_effect_disappears(m: &WbModel, d: &AxisData, what: &str) {
    let dg = diagnose(m, d, &DiagOptions::default());
    for id in EffectId::ALL {
        let ranked = dg.candidates.iter().any(|c| c.effect == id.id());
        let untested = dg.untested.iter().find(|(e, _)| e == id.id());
        assert!(
            ranked || untested.is_some_and(|(_, why)| !why.is_empty()),
            "{what}: `{id}` is neither ranked nor untested with a reason"
        );
    }
}

#[test]
fn a_requested_effect_that_cannot_be_fitted_fails_with_the_effect_and_its_reason() {
    let Some((m, d)) = emps() else { return };
    match fit(&m, &d, &[EffectId::StribeckFriction], None, 0.05) {
        Err(WorkbenchError::EffectRefused { effect, reason, .. }) => {
            assert_eq!(effect, "stribeck_friction");
            assert!(reason.contains("fs < fc"), "{reason}");
        }
        Err(e) => panic!("refused for another reason: {e}"),
        Ok(r) => panic!("fit answered {:?} instead of refusing", r.added),
    }
    // what can be fitted is fitted, and listed
    let r = fit(&m, &d, &[EffectId::CoulombFriction], None, 0.05).unwrap();
    assert_eq!(r.added, vec!["coulomb_friction".to_string()]);
}

#[test]
fn no_effect_disappears_from_a_diagnosis_of_the_emps_record() {
    let Some((m, d)) = emps() else { return };
    assert_no_effect_disappears(&m, &d, "EMPS estimation record");
}
