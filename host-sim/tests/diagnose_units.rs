//! A recording of several taps without a `tap` column: `diagnose` finds the contact episodes,
//! gives each its own contact (height, bed), and names nothing on clean taps at different
//! heights — one contact height for both would leave a misfit the size of the step.

use visco::diagnose::report::analyse;
use visco::diagnose::search::SearchOptions;
use visco::experiment::concealed::scenario;

#[test]
fn taps_at_two_heights_are_two_units_and_clean() {
    // Two clean force curves on the gel setup, the second on a surface 150 nm higher.
    let a = scenario(None, 5).recording;
    let b = scenario(None, 11).recording;
    assert_eq!(a.meta.sample_rate_hz, b.meta.sample_rate_hz);
    let mut rec = a.clone();
    let t_end = *a.t_s.last().unwrap();
    let dt = a.t_s[1] - a.t_s[0];
    for i in 0..b.len() {
        rec.t_s.push(t_end + dt + b.t_s[i]);
        rec.u_m.push(b.u_m[i] - 150e-9);
        rec.d_m.push(b.d_m[i]);
    }
    let d = analyse(&rec, &SearchOptions::default(), |_| {}).unwrap();
    let contacts = &d.search.nominal.nominal.contacts;
    assert_eq!(contacts.len(), 2, "two contact episodes");
    // Heights in nm: the second surface 150 nm lower in U (the same tip path, shifted).
    let step = contacts[0].h - contacts[1].h;
    assert!((step - 150.0).abs() < 2.0, "height step {step} nm");
    assert!(d.findings.is_empty(), "{}", d.summary());
}
