//! Self-contained HTML reports, one per run (`report.html` beside its results) and one per suite:
//! the map over the ground truth with the trajectories, errors over time, metric and gate tables
//! and the configuration. Figures are inline SVG (the map is an embedded PNG), styles inline,
//! no scripts: the page shows the same in any browser, offline, and in a CI artefact viewer.

use crate::ground_truth::trajectory;
use crate::picture::{grid_image, png};
use base64::Engine;
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::tum::Stamped;
use futago_robot::geometry::grid::OCCUPIED;
use serde_json::Value;
use std::fmt::Write;

/// HTML/XML text with `& < > " '` escaped.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&apos;")
}

/// A line of a figure.
pub struct Series {
    pub name: String,
    pub colour: &'static str,
    pub points: Vec<[f64; 2]>,
    /// Drawn as dots (a scatter) instead of a line.
    pub markers: bool,
}

/// Colours of the trajectories, by file: truth, odometry, localisation, SLAM.
const COLOURS: [(&str, &str); 4] = [
    ("groundtruth", "#1a9641"),
    ("odometry", "#d7191c"),
    ("localization", "#7b3294"),
    ("slam", "#2c7bb6"),
];

fn colour(name: &str) -> &'static str {
    COLOURS
        .iter()
        .find(|(n, _)| *n == name)
        .map_or("#555555", |c| c.1)
}

/// At most `n` points, evenly picked, the last kept.
fn thin(points: Vec<[f64; 2]>, n: usize) -> Vec<[f64; 2]> {
    if points.len() <= n {
        return points;
    }
    let step = points.len().div_ceil(n);
    let last = *points.last().expect("not empty");
    let mut out: Vec<[f64; 2]> = points.into_iter().step_by(step).collect();
    out.push(last);
    out
}

/// Tick values for an axis over `[lo, hi]`: about five, at 1, 2 or 5 times a power of ten.
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).max(1e-12);
    let raw = span / 5.0;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| span / s <= 6.0)
        .unwrap_or(10.0 * p);
    let mut t = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while t <= hi + step * 1e-9 {
        out.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    out
}

/// A line chart: `series` over shared axes, with ticks, labels and a legend.
pub fn line_chart(title: &str, x_label: &str, y_label: &str, series: &[Series]) -> String {
    line_chart_scaled(title, x_label, y_label, series, [false, false])
}

/// A line chart with each axis (x, y) linear or logarithmic; on a log axis, points at or
/// below zero are left out.
pub fn line_chart_scaled(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log: [bool; 2],
) -> String {
    let to_axis = |v: f64, k: usize| if log[k] { v.log10() } else { v };
    let series: Vec<Series> = series
        .iter()
        .map(|s| Series {
            name: s.name.clone(),
            colour: s.colour,
            markers: s.markers,
            points: s
                .points
                .iter()
                .map(|p| [to_axis(p[0], 0), to_axis(p[1], 1)])
                .filter(|p| p[0].is_finite() && p[1].is_finite())
                .collect(),
        })
        .collect();
    let label = |t: f64, k: usize| fmt_tick(if log[k] { 10f64.powf(t) } else { t });
    let (w, h, left, right, top, bottom) = (720.0, 300.0, 64.0, 16.0, 28.0, 44.0);
    let all = series.iter().flat_map(|s| s.points.iter());
    // A linear y axis starts at zero at most, so that errors are seen against nothing.
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::MAX,
        f64::MIN,
        if log[1] { f64::MAX } else { 0.0f64 },
        f64::MIN,
    );
    for p in all {
        x0 = x0.min(p[0]);
        x1 = x1.max(p[0]);
        y0 = y0.min(p[1]);
        y1 = y1.max(p[1]);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-12 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-12 {
        y1 = y0 + 1.0;
    }
    y1 += 0.05 * (y1 - y0);
    let px = |x: f64| left + (x - x0) / (x1 - x0) * (w - left - right);
    let py = |y: f64| h - bottom - (y - y0) / (y1 - y0) * (h - top - bottom);
    let mut svg = format!(
        "<svg class=\"chart\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {w} {h}\" width=\"{w}\" height=\"{h}\" role=\"img\" aria-label=\"{0}\">\n<title>{0}</title>\n<rect x=\"{left}\" y=\"{top}\" width=\"{1}\" height=\"{2}\" fill=\"#fafafa\" stroke=\"#999\"/>\n",
        escape(title),
        w - left - right,
        h - top - bottom
    );
    for t in axis_ticks(x0, x1, log[0]) {
        let x = px(t);
        let _ = writeln!(
            svg,
            "<line x1=\"{x:.1}\" y1=\"{top}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#e0e0e0\"/><text x=\"{x:.1}\" y=\"{:.1}\" font-size=\"11\" text-anchor=\"middle\">{}</text>",
            h - bottom,
            h - bottom + 14.0,
            label(t, 0)
        );
    }
    for t in axis_ticks(y0, y1, log[1]) {
        let y = py(t);
        let _ = writeln!(
            svg,
            "<line x1=\"{left}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#e0e0e0\"/><text x=\"{:.1}\" y=\"{:.1}\" font-size=\"11\" text-anchor=\"end\">{}</text>",
            w - right,
            left - 4.0,
            y + 4.0,
            label(t, 1)
        );
    }
    let _ = writeln!(
        svg,
        "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"12\" text-anchor=\"middle\">{}</text><text transform=\"translate(14 {:.1}) rotate(-90)\" font-size=\"12\" text-anchor=\"middle\">{}</text><text x=\"{left}\" y=\"18\" font-size=\"13\" font-weight=\"bold\">{}</text>",
        (left + w - right) / 2.0,
        h - 8.0,
        escape(x_label),
        (top + h - bottom) / 2.0,
        escape(y_label),
        escape(title)
    );
    for (k, s) in series.iter().enumerate() {
        if s.markers {
            let _ = write!(
                svg,
                "<g class=\"series\" data-name=\"{}\" fill=\"{}\">",
                escape(&s.name),
                s.colour
            );
            for p in &s.points {
                let _ = write!(
                    svg,
                    "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"3\"/>",
                    px(p[0]),
                    py(p[1])
                );
            }
            svg += "</g>\n";
        }
        let pts: Vec<String> = s
            .points
            .iter()
            .map(|p| format!("{:.1},{:.1}", px(p[0]), py(p[1])))
            .collect();
        if !s.markers {
            let _ = writeln!(
                svg,
                "<polyline class=\"series\" data-name=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1.5\" points=\"{}\"/>",
                escape(&s.name),
                s.colour,
                pts.join(" ")
            );
        }
        let ly = top + 14.0 + 16.0 * k as f64;
        let lx = w - right - 150.0;
        let _ = writeln!(
            svg,
            "<line x1=\"{lx}\" y1=\"{ly}\" x2=\"{}\" y2=\"{ly}\" stroke=\"{}\" stroke-width=\"3\"/><text x=\"{}\" y=\"{}\" font-size=\"11\">{}</text>",
            lx + 18.0,
            s.colour,
            lx + 24.0,
            ly + 4.0,
            escape(&s.name)
        );
    }
    svg + "</svg>\n"
}

/// Ticks of an axis; a log axis (in decades) spanning more than one and a half decades ticks
/// at powers of ten only.
fn axis_ticks(lo: f64, hi: f64, log: bool) -> Vec<f64> {
    if log && hi - lo >= 1.5 {
        let (a, b) = (lo.ceil() as i32, hi.floor() as i32);
        let step = ((b - a) / 6 + 1).max(1);
        (a..=b).step_by(step as usize).map(f64::from).collect()
    } else {
        ticks(lo, hi)
    }
}

fn fmt_tick(t: f64) -> String {
    let s = format!("{t:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

/// The map figure: the ground-truth grid (walls grey, free space white, unknown light grey),
/// the estimated map's occupied cells over it (blue), and trajectories drawn in world
/// coordinates (metres; x right, y up). The first path is the ground truth.
pub fn map_figure(
    truth: &OccupancyGrid,
    estimate: Option<&OccupancyGrid>,
    paths: &[Series],
) -> String {
    let mut img = grid_image(truth, 1);
    if let Some(est) = estimate {
        for j in 0..est.height {
            for i in 0..est.width {
                if est.get(i, j) >= OCCUPIED {
                    let [x, y] = est.cell_center(i, j);
                    if let Some((ti, tj)) = truth.cell_of(x, y) {
                        img.put_pixel(
                            ti as u32,
                            (truth.height - 1 - tj) as u32,
                            image::Rgb([30, 90, 200]),
                        );
                    }
                }
            }
        }
    }
    let data = base64::engine::general_purpose::STANDARD.encode(png(img));
    let (w, h) = (
        truth.width as f64 * truth.resolution,
        truth.height as f64 * truth.resolution,
    );
    let [ox, oy] = truth.origin;
    let px_w = 900.0f64.min(truth.width as f64 * 4.0);
    let px_h = px_w * h / w;
    let mut svg = format!(
        "<svg class=\"map\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"{ox} {} {w} {h}\" width=\"{px_w:.0}\" height=\"{px_h:.0}\" role=\"img\" aria-label=\"map over the ground truth\">\n<title>Map over the ground truth</title>\n<image href=\"data:image/png;base64,{data}\" x=\"{ox}\" y=\"{}\" width=\"{w}\" height=\"{h}\" preserveAspectRatio=\"none\" style=\"image-rendering: pixelated\"/>\n",
        -(oy + h),
        -(oy + h),
    );
    // Estimates first, the truth (the first path) last and dashed, so that both show where
    // they coincide.
    for (k, s) in paths
        .iter()
        .enumerate()
        .skip(1)
        .chain(paths.iter().enumerate().take(1))
    {
        let pts: Vec<String> = s
            .points
            .iter()
            .map(|p| format!("{:.3},{:.3}", p[0], -p[1]))
            .collect();
        let _ = writeln!(
            svg,
            "<polyline class=\"series\" data-name=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"3\" vector-effect=\"non-scaling-stroke\"{} points=\"{}\"/>",
            escape(&s.name),
            s.colour,
            if k == 0 {
                " stroke-dasharray=\"8 6\""
            } else {
                ""
            },
            pts.join(" ")
        );
    }
    svg + "</svg>\n"
}

/// An HTML table; cells are already HTML.
fn table(class: &str, head: &[&str], rows: &[Vec<String>]) -> String {
    let mut t = format!("<table class=\"{class}\"><thead><tr>");
    for h in head {
        let _ = write!(t, "<th>{}</th>", escape(h));
    }
    t += "</tr></thead><tbody>\n";
    for r in rows {
        t += "<tr>";
        for c in r {
            let _ = write!(t, "<td>{c}</td>");
        }
        t += "</tr>\n";
    }
    t + "</tbody></table>\n"
}

fn number(v: &Value) -> String {
    match v.as_f64() {
        Some(x) if x.abs() >= 1000.0 || x == x.trunc() => format!("{x}"),
        Some(x) => format!("{x:.4}"),
        None => "—".into(),
    }
}

fn status_cell(passed: bool) -> String {
    if passed {
        "<span class=\"pass\">passed</span>".into()
    } else {
        "<span class=\"fail\">failed</span>".into()
    }
}

/// Rows of a gates table from a run's `gates`.
fn gate_rows(gates: &[Value]) -> Vec<Vec<String>> {
    gates
        .iter()
        .map(|g| {
            vec![
                escape(g["metric"].as_str().unwrap_or("")),
                escape(g["op"].as_str().unwrap_or("")),
                number(&g["threshold"]),
                number(&g["value"]),
                status_cell(g["passed"] == true),
            ]
        })
        .collect()
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:24px;max-width:1100px;color:#222}\
h1{font-size:22px}h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ddd}\
table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}\
th{background:#f0f0f0}.pass{color:#1a7f37;font-weight:bold}.fail{color:#c62828;font-weight:bold}\
pre{background:#f6f6f6;padding:10px;font-size:12px;overflow:auto}.legend span{margin-right:14px}\
figure{margin:12px 0}figcaption{font-size:12px;color:#555}";

pub fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}</style></head><body>\n{body}</body></html>\n",
        escape(title)
    )
}

/// A grid reduced so that neither side exceeds `max_side` cells: each new cell is occupied if
/// any cell it covers is, else free if any is, else unknown. A drifted SLAM map can span
/// hundreds of metres; drawn at one pixel a cell its picture would take gigabytes.
pub fn downsample(grid: &OccupancyGrid, max_side: usize) -> std::borrow::Cow<'_, OccupancyGrid> {
    let f = grid.width.max(grid.height).div_ceil(max_side.max(1));
    if f <= 1 {
        return std::borrow::Cow::Borrowed(grid);
    }
    let (w, h) = (grid.width.div_ceil(f), grid.height.div_ceil(f));
    let mut out = OccupancyGrid::new(grid.resolution * f as f64, grid.origin, w, h);
    out.cells.iter_mut().for_each(|c| *c = -1);
    for j in 0..grid.height {
        for i in 0..grid.width {
            let c = grid.get(i, j);
            let o = &mut out.cells[(j / f) * w + i / f];
            if c >= OCCUPIED {
                *o = 100;
            } else if c == 0 && *o != 100 {
                *o = 0;
            }
        }
    }
    std::borrow::Cow::Owned(out)
}

/// How many of a replay's worst relations are marked on its map.
pub const WORST_RELATIONS: usize = 10;

/// A replay's relation scores (`summary.json`'s `relations`): SLAM's and odometry's, over all
/// relations and by span; nothing without relations.
fn relations_section(rel: &Value) -> String {
    let mut body = String::new();
    if !rel.is_object() {
        return body;
    }
    let row = |name: &str| {
        let m = &rel[name];
        let f = |k: &str, d: usize| {
            format!(
                "{:.d$} ± {:.d$}",
                m[k]["mean"].as_f64().unwrap_or(f64::NAN),
                m[k]["std"].as_f64().unwrap_or(f64::NAN)
            )
        };
        vec![
            name.to_string(),
            f("abs_trans_m", 4),
            f("abs_rot_deg", 3),
            number(&m["relations"]),
            number(&m["unmatched"]),
        ]
    };
    body += "<h2>Relations (Kümmerle et al. 2009)</h2>\n";
    body += &table(
        "relations",
        &[
            "trajectory",
            "abs trans (m)",
            "abs rot (°)",
            "scored",
            "unmatched",
        ],
        &[row("slam"), row("odometry")],
    );
    if let Some(groups) = rel["by_span"].as_array() {
        let mut rows = Vec::new();
        for g in groups {
            for name in ["slam", "odometry"] {
                let m = &g[name];
                rows.push(vec![
                    g["span"].as_str().unwrap_or("?").replace('_', " "),
                    name.to_string(),
                    format!(
                        "{:.4} ± {:.4}",
                        m["abs_trans_m"]["mean"].as_f64().unwrap_or(f64::NAN),
                        m["abs_trans_m"]["std"].as_f64().unwrap_or(f64::NAN)
                    ),
                    format!(
                        "{:.3} ± {:.3}",
                        m["abs_rot_deg"]["mean"].as_f64().unwrap_or(f64::NAN),
                        m["abs_rot_deg"]["std"].as_f64().unwrap_or(f64::NAN)
                    ),
                    number(&m["relations"]),
                ]);
            }
        }
        body += "<p>By the time between a relation's two poses: short spans measure local \
                 accuracy, long ones the map's consistency after loops.</p>\n";
        body += &table(
            "relations by span",
            &[
                "span",
                "trajectory",
                "abs trans (m)",
                "abs rot (°)",
                "scored",
            ],
            &rows,
        );
    }
    body
}

/// The report of a replay of a real log (deterministic: no wall times): its facts and relation
/// scores, the SLAM map with
/// the SLAM trajectory and odometry over it and the worst relations marked (a circle at each
/// end, numbered by rank), and each relation's error over time. `worst` lists the marked
/// relations, worst first: (rank label, SLAM poses at both ends, translational error m).
pub fn replay_report(
    summary: &Value,
    map: &OccupancyGrid,
    slam: &[(futago_msgs::Time, futago_msgs::Pose2)],
    odometry: &[(futago_msgs::Time, futago_msgs::Pose2)],
    errors: &[(f64, f64)],
    worst: &[([f64; 2], [f64; 2], f64)],
) -> String {
    let log = summary["log"].as_str().unwrap_or("log");
    let mut body = format!("<h1>futago replay: {}</h1>\n", escape(log));
    body += &table(
        "facts",
        &[
            "SLAM",
            "scans",
            "log",
            "keyframes",
            "loop closures",
            "unmatched scans",
        ],
        &[vec![
            escape(summary["slam"].as_str().unwrap_or("")),
            number(&summary["scans"]),
            format!("{:.0} s", summary["log_duration_s"].as_f64().unwrap_or(0.0)),
            number(&summary["keyframes"]),
            number(&summary["loop_closures"]),
            number(&summary["unmatched_scans"]),
        ]],
    );
    body += &relations_section(&summary["relations"]);
    let path =
        |name: &str, colour: &'static str, t: &[(futago_msgs::Time, futago_msgs::Pose2)]| Series {
            name: name.into(),
            colour,
            points: thin(t.iter().map(|(_, p)| [p.x, p.y]).collect(), 4000),
            markers: false,
        };
    let mut svg = map_figure(
        &downsample(map, 2000),
        None,
        &[
            path("slam", colour("slam"), slam),
            path("odometry", colour("odometry"), odometry),
        ],
    );
    // The worst relations: a circle at each end, and a line between them.
    let mut marks = String::new();
    for (k, (a, b, e)) in worst.iter().enumerate() {
        let _ = writeln!(
            marks,
            "<g class=\"worst\"><title>relation {}: {e:.3} m</title><line x1=\"{:.3}\" y1=\"{:.3}\" x2=\"{:.3}\" y2=\"{:.3}\" stroke=\"#c62828\" stroke-width=\"2\" vector-effect=\"non-scaling-stroke\"/><circle cx=\"{:.3}\" cy=\"{:.3}\" r=\"0.6\" fill=\"none\" stroke=\"#c62828\" stroke-width=\"2\" vector-effect=\"non-scaling-stroke\"/><circle cx=\"{:.3}\" cy=\"{:.3}\" r=\"0.6\" fill=\"none\" stroke=\"#c62828\" stroke-width=\"2\" vector-effect=\"non-scaling-stroke\"/><text x=\"{:.3}\" y=\"{:.3}\" font-size=\"1.2\" fill=\"#c62828\">{}</text></g>",
            k + 1,
            a[0],
            -a[1],
            b[0],
            -b[1],
            a[0],
            -a[1],
            b[0],
            -b[1],
            a[0] + 0.7,
            -a[1],
            k + 1
        );
    }
    if let Some(end) = svg.rfind("</svg>") {
        svg.insert_str(end, &marks);
    }
    body += "<h2>Map</h2>\n<figure>";
    body += &svg;
    body += &format!(
        "<figcaption>The SLAM map with its trajectory (blue, dashed) and odometry from the same start (red). In red circles, numbered by rank: the ends of the {} relations with the largest translational error, placed by SLAM.</figcaption></figure>\n",
        worst.len()
    );
    if !errors.is_empty() {
        let t0 = errors.iter().map(|e| e.0).fold(f64::INFINITY, f64::min);
        let points = errors.iter().map(|e| [e.0 - t0, e.1]).collect();
        let chart = line_chart_scaled(
            "Relation error over time",
            "time of the relation's first pose (s from the first)",
            "translational error (m)",
            &[Series {
                name: "slam".into(),
                colour: colour("slam"),
                points,
                markers: true,
            }],
            [false, true],
        );
        body += "<h2>Where it went wrong</h2>\n<figure>";
        body += &chart;
        body += "<figcaption>Each relation's translational error (log scale) at the time of its first pose.</figcaption></figure>\n";
        let rows: Vec<Vec<String>> = worst
            .iter()
            .enumerate()
            .map(|(k, (a, b, e))| {
                vec![
                    (k + 1).to_string(),
                    format!("{e:.3}"),
                    format!("({:.2}, {:.2})", a[0], a[1]),
                    format!("({:.2}, {:.2})", b[0], b[1]),
                ]
            })
            .collect();
        body += &table("worst", &["rank", "error (m)", "from (m)", "to (m)"], &rows);
    }
    body += &format!(
        "<h2>Configuration</h2>\n<pre>{}</pre>\n",
        escape(summary["config"].as_str().unwrap_or(""))
    );
    page(&format!("futago replay: {log}"), &body)
}

/// The facts of a run: world, seed, time simulated, distance driven, bumps, overlays, gates.
fn run_facts(summary: &Value, gates: &[Value]) -> String {
    let failed = gates.iter().filter(|g| g["passed"] == false).count();
    table(
        "facts",
        &[
            "world",
            "seed",
            "simulated",
            "driven",
            "bumps",
            "overlays",
            "gates",
        ],
        &[vec![
            escape(summary["world"].as_str().unwrap_or("")),
            number(&summary["seed"]),
            format!("{:.1} s", summary["sim_time_s"].as_f64().unwrap_or(0.0)),
            format!(
                "{:.2} m",
                summary["robot"]["distance_travelled_m"]
                    .as_f64()
                    .unwrap_or(0.0)
            ),
            number(&summary["robot"]["bump_events"]),
            escape(
                &summary["overlays"]
                    .as_array()
                    .map(|a| {
                        a.iter()
                            .filter_map(|o| o.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    })
                    .filter(|s| !s.is_empty())
                    .unwrap_or_else(|| "none".into()),
            ),
            if gates.is_empty() {
                "none".into()
            } else {
                format!(
                    "{} of {} passed {}",
                    gates.len() - failed,
                    gates.len(),
                    status_cell(failed == 0)
                )
            },
        ]],
    )
}

/// The report of a run, from memory: `truth_traj` is its true trajectory, `summary` its
/// summary.json, `config` the scenario text as run, `truth` the ground-truth grid,
/// `estimate` SLAM's map and `trajectories` the estimated ones.
pub fn run_report(
    truth_traj: &[Stamped],
    summary: &Value,
    config: &str,
    truth: &OccupancyGrid,
    estimate: Option<&OccupancyGrid>,
    trajectories: &[crate::stack::Trajectory],
    pictures: &[(String, Vec<u8>)],
) -> String {
    let name = summary["scenario"].as_str().unwrap_or("run");
    let gates = summary["gates"].as_array().cloned().unwrap_or_default();
    let mut body = format!(
        "<h1>futago run: {}</h1>\n<p>{}</p>\n",
        escape(name),
        escape(summary["description"].as_str().unwrap_or(""))
    );
    body += &run_facts(summary, &gates);
    if !gates.is_empty() {
        body += "<h2>Gates</h2>\n";
        body += &table(
            "gates",
            &["metric", "op", "threshold", "value", "status"],
            &gate_rows(&gates),
        );
    }
    // Trajectories and their errors.
    let mut paths = vec![Series {
        markers: false,
        name: "ground truth".into(),
        colour: colour("groundtruth"),
        points: thin(
            truth_traj
                .iter()
                .map(|p| [p.pose.translation[0], p.pose.translation[1]])
                .collect(),
            4000,
        ),
    }];
    let (mut pos_err, mut head_err) = (Vec::new(), Vec::new());
    for t in trajectories {
        let (key, est) = (t.name.as_str(), &t.poses);
        paths.push(Series {
            markers: false,
            name: key.into(),
            colour: colour(key),
            points: thin(
                est.iter()
                    .map(|p| [p.pose.translation[0], p.pose.translation[1]])
                    .collect(),
                4000,
            ),
        });
        let pairs =
            trajectory::associate_indices(truth_traj, est, crate::ground_truth::MAX_TIME_DIFF);
        let (mut pe, mut he) = (Vec::new(), Vec::new());
        for (r, e) in pairs {
            let (a, b) = (truth_traj[r].pose.to_pose2(), est[e].pose.to_pose2());
            let t = trajectory::seconds(&est[e]);
            pe.push([t, a.distance(&b)]);
            he.push([
                t,
                futago_msgs::wrap_angle(b.theta - a.theta)
                    .abs()
                    .to_degrees(),
            ]);
        }
        pos_err.push(Series {
            name: key.into(),
            colour: colour(key),
            points: thin(pe, 1500),
            markers: false,
        });
        head_err.push(Series {
            name: key.into(),
            colour: colour(key),
            points: thin(he, 1500),
            markers: false,
        });
    }
    body += "<h2>Map and trajectories</h2>\n<figure>\n";
    body += &map_figure(truth, estimate, &paths);
    body += "<figcaption class=\"legend\">";
    for s in &paths {
        let _ = write!(
            body,
            "<span style=\"color:{}\">━ {}</span>",
            s.colour,
            escape(&s.name)
        );
    }
    body += if estimate.is_some() {
        "<span>grey: true walls · blue: SLAM's occupied cells</span>"
    } else {
        "<span>grey: true walls</span>"
    };
    body += "</figcaption>\n</figure>\n";
    if !pos_err.is_empty() {
        body += "<h2>Errors over time</h2>\n<figure>\n";
        body += &line_chart(
            "Position error against the ground truth",
            "time (s)",
            "error (m)",
            &pos_err,
        );
        body += &line_chart(
            "Heading error against the ground truth",
            "time (s)",
            "error (°)",
            &head_err,
        );
        body += "</figure>\n";
    }
    let picture = |name: &str| {
        pictures
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, png)| png.as_slice())
    };
    body += &rgbd_section(picture(crate::stack::rgbd_map::RGBD_SLICE_FILE), summary);
    body += &coverage_section(picture(crate::stack::coverage::PICTURE_FILE), summary);
    body += "<h2>Metrics</h2>\n";
    let rows: Vec<Vec<String>> = summary["metrics"]
        .as_object()
        .into_iter()
        .flatten()
        .map(|(k, v)| vec![escape(k), number(v)])
        .collect();
    body += &table("metrics", &["metric", "value"], &rows);
    body += "<h2>Configuration</h2>\n<pre class=\"config\">";
    body += &escape(config);
    body += "</pre>\n";
    page(&format!("futago run: {name}"), &body)
}

/// The RGB-D map's section: each method's main scores, and the laser-height slice picture
/// (`rgbd_slice.png`, from the mapper's report) embedded; empty for a run without one.
fn rgbd_section(slice: Option<&[u8]>, summary: &Value) -> String {
    let metrics = &summary["metrics"];
    let methods: Vec<&str> = futago_robot::mapping::registration::Method::ALL
        .iter()
        .map(|m| m.name())
        .filter(|m| metrics.get(format!("rgbd_map.{m}.f1_5cm")).is_some())
        .collect();
    if methods.is_empty() {
        return String::new();
    }
    let keys = [
        ("f1_5cm", "F1 at 5 cm"),
        ("f1_1cm", "F1 at 1 cm"),
        ("mean_distance_m", "mean distance (m)"),
        ("slice_rms_m", "slice RMS (m)"),
        ("slice_thickness_m", "slice thickness (m)"),
        ("keyframe_pose.rmse_m", "keyframe RMSE (m)"),
        ("keyframe_pose.rmse_deg", "keyframe RMSE (°)"),
        ("planes.angle_mean_deg", "plane angle (°)"),
        ("planes.offset_mean_m", "plane offset (m)"),
        ("planes.faces", "faces"),
    ];
    let mut head = vec!["method"];
    head.extend(keys.iter().map(|k| k.1));
    let rows: Vec<Vec<String>> = methods
        .iter()
        .map(|m| {
            std::iter::once(escape(m))
                .chain(
                    keys.iter()
                        .map(|(k, _)| number(&metrics[format!("rgbd_map.{m}.{k}")])),
                )
                .collect()
        })
        .collect();
    let mut out = String::from("<h2>3D map</h2>\n");
    out += &table("rgbd-methods", &head, &rows);
    if let Some(png) = slice {
        out += &format!(
            "<figure>\n<img class=\"slice\" src=\"data:image/png;base64,{}\" alt=\"the first method's laser-height slice (red) over the true 2D map\" style=\"max-width: 100%\">\n<figcaption>The first method's points at the laser's height (red) over the world's 2D map.</figcaption>\n</figure>\n",
            base64::engine::general_purpose::STANDARD.encode(png)
        );
    }
    out
}

/// The coverage table's figures: metric and what the row says.
const COVERAGE_FIGURES: &[(&str, &str)] = &[
    ("coverage.footprint", "footprint (driven)"),
    ("coverage.route.footprint", "footprint (planned)"),
    (
        "coverage.footprint_of_route",
        "footprint (driven, of the planned)",
    ),
    ("coverage.camera.walls", "camera: walls"),
    ("coverage.camera.floor", "camera: floor"),
    ("coverage.camera.furniture", "camera: furniture"),
    ("coverage.camera.rooms.walls", "camera: walls of rooms"),
    (
        "coverage.camera.corridors.walls",
        "camera: walls of corridors",
    ),
    (
        "coverage.camera.regions.walls_min",
        "camera: walls of the worst region",
    ),
    (
        "coverage.camera.regions.walls_observable",
        "camera: walls it can see at all",
    ),
    ("coverage.route.length_m", "route (m)"),
    ("coverage.route.time_s", "time model (s)"),
    ("coverage.driven_m", "driven (m)"),
    (
        "coverage.second_pass.walls_before",
        "walls before the second pass",
    ),
    ("coverage.second_pass.walls_gain", "walls gained by it"),
    ("coverage.second_pass.extra_m", "its extra distance (m)"),
];

/// The coverage section: the route's and the second pass's figures, the painted map
/// (`coverage.png`, from the coverage node's report) and coverage over time; empty for a run without a coverage route.
fn coverage_section(picture: Option<&[u8]>, summary: &Value) -> String {
    let c = &summary["coverage"];
    if c.is_null() {
        return String::new();
    }
    let metrics = &summary["metrics"];
    // A kind of region the area holds none of scores 1; the table says so instead.
    let scored = |kind: &str| {
        c["regions"].as_array().is_some_and(|r| {
            r.iter()
                .any(|x| x["kind"] == kind && x["scored"].as_bool() == Some(true))
        })
    };
    let rows: Vec<Vec<String>> = COVERAGE_FIGURES
        .iter()
        .filter(|(k, _)| metrics.get(*k).is_some())
        .map(|(k, name)| {
            let none = [("rooms", "room"), ("corridors", "corridor")]
                .iter()
                .any(|(p, kind)| k.starts_with(&format!("coverage.camera.{p}.")) && !scored(kind));
            let value = if none {
                "none in the area".to_string()
            } else {
                number(&metrics[*k])
            };
            vec![escape(name), value]
        })
        .collect();
    let mut out = format!(
        "<h2>Coverage ({})</h2>\n",
        escape(c["planner"].as_str().unwrap_or(""))
    );
    out += &table("coverage", &["figure", "value"], &rows);
    let share = |v: &Value| {
        v.as_f64()
            .map_or("–".to_string(), |x| format!("{:.1} %", 100.0 * x))
    };
    let regions: Vec<Vec<String>> = c["regions"]
        .as_array()
        .into_iter()
        .flatten()
        .enumerate()
        .filter(|(_, r)| {
            r["walls_m2"].as_f64().unwrap_or(0.0) + r["floor_m2"].as_f64().unwrap_or(0.0) > 0.0
        })
        .map(|(k, r)| {
            let centre = &r["centre"];
            vec![
                k.to_string(),
                escape(r["kind"].as_str().unwrap_or("")),
                format!(
                    "{:.1}, {:.1}",
                    centre[0].as_f64().unwrap_or(0.0),
                    centre[1].as_f64().unwrap_or(0.0)
                ),
                number(&r["area_m2"]),
                share(&r["reachable_share"]),
                if r["scored"].as_bool() == Some(true) {
                    "yes"
                } else {
                    "no"
                }
                .into(),
                number(&r["walls_m2"]),
                share(&r["camera_walls"]),
                share(&r["camera_floor"]),
            ]
        })
        .collect();
    if !regions.is_empty() {
        out += "<h3>Camera coverage by region</h3>\n";
        out += &table(
            "coverage-regions",
            &[
                "region",
                "kind",
                "centre (m)",
                "floor (m²)",
                "reachable",
                "scored",
                "walls (m²)",
                "walls seen",
                "floor seen",
            ],
            &regions,
        );
    }
    if let Some(png) = picture {
        out += &format!(
            "<figure>\n<img class=\"coverage\" src=\"data:image/png;base64,{}\" alt=\"the map painted by coverage\" style=\"max-width: 100%\">\n<figcaption>Floor swept green, reachable floor not swept orange; walls and furniture the camera saw blue, not seen red; the planned route dark blue, the second route magenta, the driven path black.</figcaption>\n</figure>\n",
            base64::engine::general_purpose::STANDARD.encode(png)
        );
    }
    let series = c["series"].as_array().cloned().unwrap_or_default();
    let line = |key: &str, name: &str, colour: &'static str| Series {
        name: name.into(),
        colour,
        points: series
            .iter()
            .filter_map(|p| Some([p["t"].as_f64()?, p[key].as_f64()?]))
            .collect(),
        markers: false,
    };
    if !series.is_empty() {
        out += "<figure>\n";
        out += &line_chart(
            "Coverage over time",
            "time (s)",
            "share",
            &[
                line("footprint", "footprint", "#1a9641"),
                line("camera_walls", "camera: walls", "#2c7bb6"),
                line("camera_floor", "camera: floor", "#fdae61"),
            ],
        );
        out += "</figure>\n";
    }
    out
}

/// The report of a suite from its summary (suite.json): runs with their status and gates, each
/// gate's headroom as a figure, sweeps' mean and spread, and links to the runs' reports
/// (`links[k]`, relative to the suite's report, for result `k`).
pub fn suite_report(summary: &Value, links: &[Option<String>]) -> String {
    let results = summary["results"].as_array().cloned().unwrap_or_default();
    let mut body = format!(
        "<h1>futago suite</h1>\n<p>{} runs: {} passed, {} failed, {} errors, in {:.1} s.</p>\n",
        summary["scenarios"],
        summary["passed"],
        summary["failed"],
        summary["errors"],
        summary["wall_time_s"].as_f64().unwrap_or(0.0)
    );
    body += "<h2>Runs</h2>\n";
    let rows: Vec<Vec<String>> = results
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let name = escape(r["scenario"].as_str().unwrap_or(""));
            let gates = r["gates"].as_array().cloned().unwrap_or_default();
            let ok = gates.iter().filter(|g| g["passed"] == true).count();
            let status = r["status"].as_str().unwrap_or("");
            let failures: Vec<String> = gates
                .iter()
                .filter(|g| g["passed"] == false)
                .filter_map(|g| g["message"].as_str().map(escape))
                .chain(r["error"].as_str().map(escape))
                .collect();
            vec![
                match links.get(k).cloned().flatten() {
                    Some(l) => format!("<a href=\"{}\">{name}</a>", escape(&l)),
                    None => name,
                },
                format!(
                    "<span class=\"{}\">{status}</span>",
                    if status == "passed" { "pass" } else { "fail" }
                ),
                format!("{ok} of {}", gates.len()),
                format!("{:.1}", r["wall_time_s"].as_f64().unwrap_or(0.0)),
                failures.join("<br>"),
            ]
        })
        .collect();
    body += &table(
        "runs",
        &["run", "status", "gates", "wall time (s)", "failures"],
        &rows,
    );
    let bars: Vec<(String, f64, bool)> = results
        .iter()
        .flat_map(|r| {
            let run = r["scenario"].as_str().unwrap_or("").to_string();
            r["gates"]
                .as_array()
                .cloned()
                .unwrap_or_default()
                .into_iter()
                .map(move |g| (run.clone(), g))
        })
        .map(|(run, g)| {
            let (v, t) = (
                g["value"].as_f64().unwrap_or(f64::NAN),
                g["threshold"].as_f64().unwrap_or(0.0),
            );
            let less = g["op"].as_str().is_some_and(|o| o.starts_with('<'));
            let margin = if less { t - v } else { v - t };
            let headroom = if v.is_nan() {
                -1.0
            } else {
                (margin / t.abs().max(1e-12)).clamp(-1.0, 1.0)
            };
            (
                format!(
                    "{run}: {} {} {}",
                    g["metric"].as_str().unwrap_or(""),
                    g["op"].as_str().unwrap_or(""),
                    t
                ),
                headroom,
                g["passed"] == true,
            )
        })
        .collect();
    if !bars.is_empty() {
        body += "<h2>Gate headroom</h2>\n<figure>\n";
        body += &headroom_chart(&bars);
        body += "<figcaption>How far each gate's value is from its threshold, as a share of the threshold (clipped to ±100 %); right of zero passes.</figcaption>\n</figure>\n";
    }
    if let Some(sw) = summary["sweeps"].as_object().filter(|s| !s.is_empty()) {
        body += "<h2>Seed sweeps</h2>\n";
        let mut rows = Vec::new();
        for (stem, s) in sw {
            for (m, v) in s["metrics"].as_object().into_iter().flatten() {
                rows.push(vec![
                    escape(stem),
                    format!(
                        "{} of {}",
                        s["passed"],
                        s["seeds"].as_array().map_or(0, |a| a.len())
                    ),
                    escape(m),
                    number(&v["mean"]),
                    number(&v["std"]),
                    number(&v["min"]),
                    number(&v["max"]),
                ]);
            }
        }
        body += &table(
            "sweeps",
            &[
                "scenario",
                "seeds passed",
                "metric",
                "mean",
                "std",
                "min",
                "max",
            ],
            &rows,
        );
    }
    page("futago suite", &body)
}

/// Horizontal bars of gate headroom in [-1, 1], green where the gate passed.
fn headroom_chart(bars: &[(String, f64, bool)]) -> String {
    let (w, row, left) = (900.0, 18.0, 430.0);
    let h = 30.0 + row * bars.len() as f64;
    let mid = left + (w - left - 20.0) / 2.0;
    let half = (w - left - 20.0) / 2.0;
    let mut svg = format!(
        "<svg class=\"chart\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {w} {h}\" width=\"{w}\" height=\"{h}\" role=\"img\" aria-label=\"gate headroom\">\n<title>Gate headroom</title>\n"
    );
    for (k, (label, v, passed)) in bars.iter().enumerate() {
        let y = 20.0 + row * k as f64;
        let (x, bw) = if *v >= 0.0 {
            (mid, v * half)
        } else {
            (mid + v * half, -v * half)
        };
        let _ = writeln!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"11\" text-anchor=\"end\">{}</text><rect class=\"bar\" x=\"{x:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\"/>",
            left - 6.0,
            y + row * 0.65,
            escape(label),
            y + 2.0,
            bw.max(1.0),
            row - 4.0,
            if *passed { "#1a9641" } else { "#d7191c" }
        );
    }
    let _ = writeln!(
        svg,
        "<line x1=\"{mid}\" y1=\"10\" x2=\"{mid}\" y2=\"{h}\" stroke=\"#333\"/><text x=\"{mid}\" y=\"10\" font-size=\"10\" text-anchor=\"middle\">0</text><text x=\"{:.0}\" y=\"10\" font-size=\"10\" text-anchor=\"middle\">−100 %</text><text x=\"{:.0}\" y=\"10\" font-size=\"10\" text-anchor=\"middle\">+100 %</text>",
        mid - half + 14.0,
        mid + half - 14.0
    );
    svg + "</svg>\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_map_is_drawn_coarser_keeping_its_walls() {
        // 6 × 4 cells: free except one wall cell and an unknown corner block.
        let mut g = OccupancyGrid::new(0.05, [1.0, 2.0], 6, 4);
        g.cells.iter_mut().for_each(|c| *c = 0);
        g.set(5, 0, 100);
        for (i, j) in [(0, 2), (1, 2), (0, 3), (1, 3)] {
            g.set(i, j, -1);
        }
        let d = downsample(&g, 3);
        assert_eq!(
            (d.width, d.height, d.resolution, d.origin),
            (3, 2, 0.1, [1.0, 2.0])
        );
        assert_eq!(d.cells, vec![0, 0, 100, -1, 0, 0]);
        assert!(matches!(downsample(&g, 6), std::borrow::Cow::Borrowed(_)));
    }

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(
            ticks(0.0, 1.0),
            vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
        );
        let t = ticks(3.0, 97.0);
        assert_eq!(t.first(), Some(&20.0));
        assert!(t.windows(2).all(|w| (w[1] - w[0] - 20.0).abs() < 1e-9));
        assert_eq!(fmt_tick(0.6000000000000001), "0.6");
    }

    #[test]
    fn charts_place_points_on_their_axes() {
        let svg = line_chart(
            "t",
            "x",
            "y",
            &[Series {
                name: "a<b".into(),
                colour: "#000",
                points: vec![[0.0, 0.0], [10.0, 2.0]],
                markers: false,
            }],
        );
        // x from 0 to 10 spans the plot's 64..704 px; y 0 sits on its bottom edge (256 px).
        assert!(svg.contains("points=\"64.0,256.0 704.0,"), "{svg}");
        assert!(svg.contains("data-name=\"a&lt;b\""));
        // On log axes, 1 to 100 spans the plot and 10 sits halfway; the tick labels are the
        // values, not their logarithms.
        let svg = line_chart_scaled(
            "t",
            "x",
            "y",
            &[Series {
                name: "a".into(),
                colour: "#000",
                points: vec![[1.0, 1.0], [10.0, 10.0], [100.0, 100.0], [0.0, 5.0]],
                markers: false,
            }],
            [true, true],
        );
        assert!(svg.contains("points=\"64.0,256.0 384.0,"), "{svg}");
        assert!(
            svg.contains(">100</text>") && !svg.contains(">2</text>"),
            "{svg}"
        );
    }

    #[test]
    fn the_map_figure_embeds_the_grid_in_world_coordinates() {
        let mut g = OccupancyGrid::new(0.5, [-1.0, 2.0], 4, 2);
        g.set(0, 0, 100);
        let svg = map_figure(
            &g,
            None,
            &[Series {
                name: "truth".into(),
                colour: "#000",
                points: vec![[0.0, 2.5]],
                markers: false,
            }],
        );
        // 2 m by 1 m from (-1, 2); SVG y points down, so the top edge is -(2 + 1).
        assert!(svg.contains("viewBox=\"-1 -3 2 1\""), "{svg}");
        assert!(svg.contains("data:image/png;base64,"));
        // The slice picture: a point lands on its pixel, red, over the grid's colours.
        let mut g = OccupancyGrid::new(0.05, [-1.0, -1.0], 4, 2);
        g.cells = vec![100, 0, 0, 0, -1, -1, -1, -1];
        let png = crate::picture::points_over_map_png(&g, &[[-0.995, -0.995], [-0.805, -0.905]], 5);
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (20, 10));
        // (-0.995, -0.995): first pixel of the bottom-left cell, bottom row of the image.
        assert_eq!(img.get_pixel(0, 9).0, [220, 30, 30]);
        assert_eq!(img.get_pixel(1, 9).0, [120, 120, 120]);
        // (-0.805, -0.905): x pixel 19, y pixel 9 from the bottom.
        assert_eq!(img.get_pixel(19, 0).0, [220, 30, 30]);
        assert_eq!(img.get_pixel(10, 8).0, [255, 255, 255]);
        assert_eq!(img.get_pixel(10, 2).0, [220, 220, 220]);
        assert!(svg.contains("points=\"0.000,-2.500\""));
    }
}
