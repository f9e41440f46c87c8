//! The one SVG plotting module every feedloop plot is drawn with: the tune heat map, the Bode
//! plot of `identify stiffness`, the deviation plot of `identify inertia`, `latency.svg` and the
//! plots of the workbench reports.
//!
//! A [`Plot`] is a title, two [`Axis`] (label and unit, linear or log, ticks at 1-2-5 steps or
//! given ones), curves ([`Series`]: lines, dashed lines or dots), reference lines ([`Mark`]) and
//! shaded x intervals, with a legend naming every curve and reference line. [`stacked`] puts
//! panels over one another under one title (the Bode plot's magnitude and phase); [`HeatMap`]
//! draws a grid of values with a colour scale and an optional marked cell.
//!
//! Parts carry a `class` (`title`, `x-label`, `y-label`, `x-tick`, `y-tick`, `legend`,
//! `series`, `ref-line`, `colour-scale`, `marker`) so tests can check that a plot has them. No external
//! libraries; plain SVG 1.1 that browsers and converters render alike.

mod axis;
mod draw;
mod figure;
mod heatmap;
mod series;

pub use axis::{log_ticks, nice_ticks, Axis};
pub use figure::{stacked, Plot};
pub use heatmap::HeatMap;
pub use series::{esc, Mark, Series, Style, PALETTE};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_fall_on_1_2_5_steps_and_are_never_fewer_than_three() {
        assert_eq!(
            nice_ticks(0.0, 10.0, 5),
            vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
        );
        assert_eq!(nice_ticks(-180.0, 180.0, 4), vec![-100.0, 0.0, 100.0]);
        let t = nice_ticks(0.13, 0.31, 6);
        assert!(t.len() >= 3, "{t:?}");
        let t = nice_ticks(1.0, 1.9, 1);
        assert!(t.len() >= 3, "{t:?}");
        assert_eq!(log_ticks(1.0, 1000.0), vec![1.0, 10.0, 100.0, 1000.0]);
        assert_eq!(log_ticks(3.0, 40.0), vec![5.0, 10.0, 20.0]);
        assert_eq!(log_ticks(12.0, 30.0), vec![15.0, 20.0, 25.0, 30.0]);
    }

    #[test]
    fn an_si_axis_takes_the_prefix_of_its_values() {
        let p = Plot::new(
            "d",
            Axis::linear("time", "s"),
            Axis::linear("deviation", "m").si(),
        )
        .series(Series::line("a", "red", &[0.0, 1.0], &[0.0, 4e-6]));
        let s = p.svg();
        assert!(s.contains(">deviation (um)<"), "{s}");
        assert!(s.contains(">time (s)<"), "{s}");
        assert!(s.contains(">4<") && s.contains(">2<"), "{s}");
    }

    #[test]
    fn a_plot_has_its_title_axes_ticks_legend_and_reference_lines() {
        let x: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = x.iter().map(|v| v.sin()).collect();
        let s = Plot::new(
            "sine <test>",
            Axis::linear("time", "s"),
            Axis::linear("torque", "N m"),
        )
        .series(Series::line("sine", PALETTE[0], &x, &y))
        .hline(Mark::new("limit 0.5 N m", 0.5, "black"))
        .vline(Mark::new("t = 2 s", 2.0, "red"))
        .svg();
        assert!(s.contains(r#"class="title""#) && s.contains("sine &lt;test&gt;"));
        assert!(s.contains(">time (s)<") && s.contains(">torque (N m)<"));
        assert!(s.matches(r#"class="x-tick""#).count() > 2);
        assert!(s.matches(r#"class="y-tick""#).count() > 2);
        assert!(s.contains(r#"class="legend""#) && s.contains(">limit 0.5 N m<"));
        assert_eq!(s.matches(r#"class="ref-line""#).count(), 2);
    }

    #[test]
    fn a_heat_map_has_a_colour_scale_and_its_marker() {
        let m = HeatMap {
            title: "E".into(),
            x: Axis::linear("kp", "1/s"),
            y: Axis::linear("kv", "N m s/rad"),
            xs: vec![10.0, 20.0, 30.0],
            ys: vec![1.0, 2.0],
            values: vec![vec![1.0, 2.0, f64::NAN], vec![3.0, 0.5, 4.0]],
            value_label: "E (m)".into(),
            log_colour: true,
            missing: "rejected".into(),
            marker: Some((1, 1, "best".into())),
        };
        let s = m.svg();
        assert!(s.contains(r#"class="colour-scale""#) && s.contains(">E (m) (log scale)<"));
        assert!(s.contains(r#"class="marker""#) && s.contains(">best<"));
        assert!(s.contains(">rejected<"));
        assert!(s.matches(r#"class="x-tick""#).count() > 2);
    }
}
