//! The percentile plot of `latency.svg`, drawn with [`crate::plot`].

use hdrhistogram::Histogram;

use feedloop_model::units::si;

use crate::plot::{Axis, Mark, Plot, Series, PALETTE};

/// The reference loops measured before the run, for [`percentile_svg`].
pub struct ReferenceLoops<'a> {
    /// Wake-up lateness of the sleeping (cyclictest-style) loop, ns.
    pub sleeping: &'a Histogram<u64>,
    /// Longest stretch the bare spinning loop lost its core, ns.
    pub spinning_max_ns: u64,
}

/// Percentiles drawn: x = -log10(1 - q), from p0 to p99.999.
const TAIL: f64 = 5.0;

/// Latency and jitter over percentiles (a log time axis, the tail stretched), with the control
/// period and, when measured, the reference loops: the sleeping loop's wake-up lateness as a
/// dashed curve and the spinning loop's longest core loss as a line.
pub fn percentile_svg(
    lat: &Histogram<u64>,
    jit: &Histogram<u64>,
    period_ns: u64,
    reference: Option<&ReferenceLoops>,
) -> String {
    let xs: Vec<f64> = (0..=100).map(|i| i as f64 * TAIL / 100.0).collect();
    // us; a zero (below the histogram's 1 ns) is drawn at 1 ns so the log axis can show it
    let curve = |h: &Histogram<u64>| -> Vec<f64> {
        xs.iter()
            .map(|x| {
                let q = (1.0 - 10f64.powf(-x)).clamp(0.0, 1.0);
                (h.value_at_quantile(q) as f64).max(1.0) / 1000.0
            })
            .collect()
    };
    let ticks = [
        (0.0, "0"),
        (2f64.log10(), "50"),
        (1.0, "90"),
        (2.0, "99"),
        (3.0, "99.9"),
        (4.0, "99.99"),
        (5.0, "99.999"),
    ]
    .iter()
    .map(|(x, l)| (*x, l.to_string()))
    .collect();
    let period_us = period_ns as f64 / 1000.0;
    let mut p = Plot::new(
        "feedloop bench latency: round trip and wake-up jitter by percentile",
        Axis::linear("percentile", "%")
            .range(0.0, TAIL)
            .ticks(ticks),
        Axis::log("time", "us"),
    )
    .size(860.0, 440.0)
    .series(Series::line(
        "round trip (sample published -> command received)",
        PALETTE[0],
        &xs,
        &curve(lat),
    ))
    .series(Series::line(
        "plant wake-up lateness (jitter)",
        PALETTE[1],
        &xs,
        &curve(jit),
    ));
    if let Some(r) = reference {
        p = p.series(Series::dashed(
            "reference: sleeping loop wake-up lateness",
            "#7f7f7f",
            &xs,
            &curve(r.sleeping),
        ));
        // a loss is counted from half a period on; without one there is no line to draw, but
        // the legend says so
        let spinning = if r.spinning_max_ns > 0 {
            Mark::new(
                &format!(
                    "reference: bare spinning loop, longest core loss {}",
                    si(r.spinning_max_ns as f64 * 1e-9, "s")
                ),
                r.spinning_max_ns as f64 / 1000.0,
                PALETTE[3],
            )
        } else {
            Mark::new(
                &format!(
                    "reference: bare spinning loop, no core loss >= {}",
                    si(period_ns as f64 * 0.5e-9, "s")
                ),
                f64::NAN,
                PALETTE[3],
            )
        };
        p = p.hline(spinning);
    }
    p.hline(Mark::new(
        &format!("control period {}", si(period_us * 1e-6, "s")),
        period_us,
        "black",
    ))
    .svg()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hist(values_ns: &[u64]) -> Histogram<u64> {
        let mut h = crate::latency::ns_histogram().unwrap();
        for v in values_ns {
            h.record(*v).unwrap();
        }
        h
    }

    #[test]
    fn the_latency_plot_has_its_axes_legend_period_and_reference_loops() {
        let lat = hist(&(1..2000).map(|i| 20_000 + 10 * i).collect::<Vec<_>>());
        let jit = hist(&(1..2000).map(|i| 1_000 + 5 * i).collect::<Vec<_>>());
        let sleeping = hist(&(1..2000).map(|i| 2_000 + 7 * i).collect::<Vec<_>>());
        let r = ReferenceLoops {
            sleeping: &sleeping,
            spinning_max_ns: 350_000,
        };
        let s = percentile_svg(&lat, &jit, 100_000, Some(&r));
        assert!(s.contains(r#"class="title""#), "{s}");
        assert!(s.contains(">percentile (%)<") && s.contains(">time (us, log scale)<"));
        assert!(s.matches(r#"class="x-tick""#).count() > 2);
        assert!(s.matches(r#"class="y-tick""#).count() > 2);
        assert!(s.contains(">control period 100 us<"));
        assert!(s.contains(">reference: sleeping loop wake-up lateness<"));
        assert!(s.contains(">reference: bare spinning loop, longest core loss 350 us<"));
        assert_eq!(s.matches(r#"class="ref-line""#).count(), 2);
        // a spinning loop that never lost its core: said in the legend, no line
        let calm = ReferenceLoops {
            sleeping: &sleeping,
            spinning_max_ns: 0,
        };
        let s = percentile_svg(&lat, &jit, 100_000, Some(&calm));
        assert!(s.contains(">reference: bare spinning loop, no core loss &gt;= 50 us<"));
        assert_eq!(s.matches(r#"class="ref-line""#).count(), 1);
        // without reference loops: the period line only
        let s = percentile_svg(&lat, &jit, 250_000, None);
        assert!(s.contains(">control period 250 us<") && !s.contains("reference:"));
    }
}
