//! Textures: PNG images and the project's procedural patterns, rasterised to sRGB RGBA8.
//!
//! Procedural textures exist so that the worlds ship with no external assets and still give a
//! camera something to see: posters and panels give visual features (seed 001 localises on
//! them), bricks and noise break up plain walls. Random patterns are seeded and deterministic.

use super::spec::Pattern;
use futago_render::Texture;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn to_u8(c: [f64; 3]) -> [u8; 4] {
    let q = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [q(c[0]), q(c[1]), q(c[2]), 255]
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

/// Smooth value noise on a `cells`-periodic lattice, in [0, 1].
fn value_noise(lattice: &[f64], cells: usize, u: f64, v: f64) -> f64 {
    let (x, y) = (u * cells as f64, v * cells as f64);
    let (x0, y0) = (x.floor() as usize % cells, y.floor() as usize % cells);
    let (x1, y1) = ((x0 + 1) % cells, (y0 + 1) % cells);
    let (fx, fy) = (x.fract(), y.fract());
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let at = |i: usize, j: usize| lattice[j * cells + i];
    let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * s(fx);
    let bot = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * s(fx);
    top + (bot - top) * s(fy)
}

/// Rasterises a procedural pattern to a square `resolution`² texture, tileable.
pub fn procedural(
    pattern: Pattern,
    c1: [f64; 3],
    c2: [f64; 3],
    seed: u64,
    resolution: u32,
) -> Texture {
    let n = resolution as usize;
    let mut rgba = vec![0u8; n * n * 4];
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7465_7874_7572_6500);
    let put = |rgba: &mut [u8], i: usize, j: usize, c: [f64; 3]| {
        rgba[(j * n + i) * 4..(j * n + i) * 4 + 4].copy_from_slice(&to_u8(c));
    };
    match pattern {
        Pattern::Checker => {
            for j in 0..n {
                for i in 0..n {
                    let odd = (i * 2 / n + j * 2 / n) % 2 == 1;
                    put(&mut rgba, i, j, if odd { c2 } else { c1 });
                }
            }
        }
        Pattern::Stripes => {
            for j in 0..n {
                for i in 0..n {
                    put(&mut rgba, i, j, if (j * 8 / n) % 2 == 1 { c2 } else { c1 });
                }
            }
        }
        Pattern::Bricks => {
            // 4 courses of 2 bricks per tile, mortar lines 1/32 of the tile.
            let mortar = (n / 32).max(1);
            for j in 0..n {
                let course = j * 4 / n;
                let offset = if course % 2 == 1 { n / 4 } else { 0 };
                for i in 0..n {
                    let x = (i + offset) % (n / 2);
                    let y = j % (n / 4);
                    let shade =
                        0.9 + 0.1 * (((i + offset) / (n / 2) + course * 3) % 3) as f64 / 2.0;
                    let c = if x < mortar || y < mortar {
                        c2
                    } else {
                        c1.map(|v| v * shade)
                    };
                    put(&mut rgba, i, j, c);
                }
            }
        }
        Pattern::Noise => {
            let octaves = [(4usize, 0.5), (16, 0.3), (64, 0.2)];
            let lattices: Vec<Vec<f64>> = octaves
                .iter()
                .map(|&(c, _)| (0..c * c).map(|_| rng.random::<f64>()).collect())
                .collect();
            for j in 0..n {
                for i in 0..n {
                    let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                    let t: f64 = octaves
                        .iter()
                        .zip(&lattices)
                        .map(|(&(c, w), l)| w * value_noise(l, c, u, v))
                        .sum();
                    put(&mut rgba, i, j, mix(c1, c2, t));
                }
            }
        }
        Pattern::Poster => {
            // A background with a border, coloured blocks and "text" bars: corners and edges
            // that feature detectors find, different for every seed.
            for j in 0..n {
                for i in 0..n {
                    put(&mut rgba, i, j, c1);
                }
            }
            let border = n / 24;
            let rect = |rgba: &mut [u8], x0: usize, y0: usize, w: usize, h: usize, c: [f64; 3]| {
                for j in y0..(y0 + h).min(n) {
                    for i in x0..(x0 + w).min(n) {
                        put(rgba, i, j, c);
                    }
                }
            };
            rect(&mut rgba, 0, 0, n, border, c2);
            rect(&mut rgba, 0, n - border, n, border, c2);
            rect(&mut rgba, 0, 0, border, n, c2);
            rect(&mut rgba, n - border, 0, border, n, c2);
            for _ in 0..6 {
                let c = [
                    rng.random::<f64>(),
                    rng.random::<f64>(),
                    rng.random::<f64>(),
                ];
                let (w, h) = (
                    rng.random_range(n / 8..n / 3),
                    rng.random_range(n / 8..n / 3),
                );
                let (x, y) = (
                    rng.random_range(border..n - border - w),
                    rng.random_range(border..n / 2),
                );
                rect(&mut rgba, x, y, w, h, c);
            }
            let line_h = (n / 32).max(1);
            let mut y = n * 5 / 8;
            while y + line_h < n - 2 * border {
                let mut x = 2 * border;
                while x < n - 3 * border {
                    let w = rng.random_range(n / 24..n / 8).min(n - 2 * border - x);
                    rect(&mut rgba, x, y, w, line_h, c2);
                    x += w + n / 40 + 1;
                }
                y += 2 * line_h;
            }
        }
        Pattern::Panel => {
            // A door-like panel: a frame, two recessed panels and a handle.
            for j in 0..n {
                for i in 0..n {
                    let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                    let frame = !(0.06..0.94).contains(&u) || !(0.03..0.97).contains(&v);
                    let upper = (0.15..0.85).contains(&u) && (0.08..0.45).contains(&v);
                    let lower = (0.15..0.85).contains(&u) && (0.52..0.92).contains(&v);
                    let handle = (0.80..0.88).contains(&u) && (0.47..0.50).contains(&v);
                    let c = if handle {
                        [0.75, 0.75, 0.7]
                    } else if frame {
                        c2
                    } else if upper || lower {
                        c1.map(|x| x * 0.85)
                    } else {
                        c1
                    };
                    put(&mut rgba, i, j, c);
                }
            }
        }
    }
    Texture {
        name: format!("{pattern:?}").to_lowercase(),
        width: resolution,
        height: resolution,
        rgba,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_are_deterministic_and_seed_dependent() {
        let a = procedural(Pattern::Poster, [0.9; 3], [0.1; 3], 7, 64);
        let b = procedural(Pattern::Poster, [0.9; 3], [0.1; 3], 7, 64);
        let c = procedural(Pattern::Poster, [0.9; 3], [0.1; 3], 8, 64);
        assert_eq!(a, b);
        assert_ne!(a.rgba, c.rgba);
        assert_eq!(a.rgba.len(), 64 * 64 * 4);
    }

    #[test]
    fn checker_alternates_its_two_colours() {
        let t = procedural(Pattern::Checker, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0, 8);
        assert_eq!(&t.rgba[0..4], &[255, 0, 0, 255]);
        let right = (4 * 4) as usize; // pixel (4, 0)
        assert_eq!(&t.rgba[right..right + 4], &[0, 0, 255, 255]);
        let m = t.mean_color();
        assert!((m[0] - 0.5).abs() < 1e-9 && (m[2] - 0.5).abs() < 1e-9);
    }
}
