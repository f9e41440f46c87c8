//! The percentile plot of `latency.svg`.

use hdrhistogram::Histogram;

/// A percentile plot (latency and jitter, log-scaled tail axis) as a standalone SVG.
pub fn percentile_svg(lat: &Histogram<u64>, jit: &Histogram<u64>) -> String {
    let (w, h, l, r, t, b) = (720.0, 420.0, 70.0, 20.0, 30.0, 60.0);
    // x: -log10(1 - q) from 0 (p0) to 5 (p99.999)
    let qs: Vec<f64> = (0..=100).map(|i| i as f64 * 0.05).collect();
    let val = |hist: &Histogram<u64>, x: f64| {
        let q = (1.0 - 10f64.powf(-x)).clamp(0.0, 1.0);
        hist.value_at_quantile(q) as f64 / 1000.0
    };
    let ymax = qs
        .iter()
        .map(|x| val(lat, *x).max(val(jit, *x)))
        .fold(1.0f64, f64::max);
    let (ylo, yhi) = (0.1f64.log10(), (ymax * 1.5).log10());
    let px = |x: f64| l + (w - l - r) * x / 5.0;
    let py = |y: f64| t + (h - t - b) * (1.0 - ((y.max(0.1).log10() - ylo) / (yhi - ylo)));
    let line = |hist: &Histogram<u64>| {
        qs.iter()
            .map(|x| format!("{:.1},{:.1}", px(*x), py(val(hist, *x))))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let mut s = format!(
        "<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>\
         <rect width='100%' height='100%' fill='white'/>\
         <text x='{l}' y='18' font-size='14'>feedloop bench latency: percentiles (us, log scale)</text>"
    );
    for (x, label) in [
        (0.0, "p0"),
        (0.301, "p50"),
        (1.0, "p90"),
        (2.0, "p99"),
        (3.0, "p99.9"),
        (4.0, "p99.99"),
        (5.0, "p99.999"),
    ] {
        s += &format!(
            "<line x1='{0:.1}' x2='{0:.1}' y1='{t}' y2='{1}' stroke='#ddd'/><text x='{0:.1}' y='{2}' text-anchor='middle'>{label}</text>",
            px(x),
            h - b,
            h - b + 16.0
        );
    }
    let mut y = 10f64.powf(ylo.ceil());
    while y.log10() <= yhi {
        s += &format!(
            "<line x1='{l}' x2='{0}' y1='{1:.1}' y2='{1:.1}' stroke='#ddd'/><text x='{2}' y='{3:.1}' text-anchor='end'>{y}</text>",
            w - r,
            py(y),
            l - 6.0,
            py(y) + 4.0
        );
        y *= 10.0;
    }
    s += &format!(
        "<polyline fill='none' stroke='#1f77b4' stroke-width='2' points='{}'/>",
        line(lat)
    );
    s += &format!(
        "<polyline fill='none' stroke='#d62728' stroke-width='2' points='{}'/>",
        line(jit)
    );
    s += &format!(
        "<text x='{0}' y='{1}' fill='#1f77b4'>round trip (sample -> command)</text><text x='{0}' y='{2}' fill='#d62728'>plant wake-up lateness (jitter)</text>",
        l + 10.0,
        t + 16.0,
        t + 32.0
    );
    s += &format!(
        "<text x='{0}' y='{1}' text-anchor='middle'>percentile</text></svg>\n",
        (l + w - r) / 2.0,
        h - 12.0
    );
    s
}
