//! Map pollution by people (written for futago): how much of a map is people rather than the
//! building.
//!
//! A map point is pollution when it lies where people walked and not on static geometry:
//! - where people walked: within [`PATH_RADIUS`] of a person's true position at some
//!   ground-truth tick. A foot is up to 0.4 m from the body's centre at the longest step
//!   (steps of 0.65–0.8 m), a shin 0.05 m thick; 0.5 m covers both and half a 0.1 m cell.
//! - static geometry: the world's own occupancy (the laser's height band for a 2D map; every
//!   obstacle up to [`HEAD_ROOM`] for a 3D one), within [`STATIC_TOLERANCE`]: the maps are
//!   not scored for accuracy here, only for what they hold that the building does not.
//!
//! The score is the share of the map's occupied cells (2D) or points (3D) that are pollution.
//! A 3D point on the floor (no higher than [`FLOOR`]) or above the people's heads is never
//! pollution.

use super::map::wall_distances;
use futago_msgs::grid::OccupancyGrid;
use futago_robot::geometry::grid::OCCUPIED;
use futago_sim::people::PersonTruth;
use rustc_hash::FxHashSet;

/// A map point within this of a person's true position at some tick lies on their path, m.
pub const PATH_RADIUS: f64 = 0.5;
/// A map point within this of the world's static obstacles is on them, m (a 5 cm map's cell
/// and a half, and the maps' few centimetres of registration error).
pub const STATIC_TOLERANCE: f64 = 0.15;
/// 3D points no higher than this are on the floor, m (the Kinect's depth noise at 4 m is
/// about 3 cm, `sensors-robot-metrics.md` §2).
pub const FLOOR: f64 = 0.1;
/// 3D points above this are above every person's head, m (the tallest body futago builds is
/// under 1.9 m).
pub const HEAD_ROOM: f64 = 2.0;
/// Cell of the path raster, m.
const CELL: f64 = 0.1;

/// Where people walked: the union of discs of [`PATH_RADIUS`] about every person's position
/// at every ground-truth tick, on a 0.1 m raster.
#[derive(Debug, Default, Clone)]
pub struct PeoplePaths {
    centres: FxHashSet<[i64; 2]>,
    cells: FxHashSet<[i64; 2]>,
}

fn cell(p: [f64; 2]) -> [i64; 2] {
    [(p[0] / CELL).floor() as i64, (p[1] / CELL).floor() as i64]
}

impl PeoplePaths {
    /// Adds the people's positions at one tick.
    pub fn add(&mut self, people: &[PersonTruth]) {
        for p in people {
            self.add_position([p.pose.x, p.pose.y]);
        }
    }

    /// Adds one person's position.
    pub fn add_position(&mut self, p: [f64; 2]) {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return;
        }
        let c = cell(p);
        if !self.centres.insert(c) {
            return;
        }
        // Every cell whose centre lies within the radius of this cell's centre.
        let reach = (PATH_RADIUS / CELL).ceil() as i64;
        let r2 = (PATH_RADIUS / CELL).powi(2);
        for dj in -reach..=reach {
            for di in -reach..=reach {
                if (di * di + dj * dj) as f64 <= r2 {
                    self.cells.insert([c[0] + di, c[1] + dj]);
                }
            }
        }
    }

    /// Whether `p` lies on someone's path.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        self.cells.contains(&cell(p))
    }

    /// The share of `points` (x, y) that lie on the paths and further than
    /// [`STATIC_TOLERANCE`] from the obstacles of `world`; `None` without points.
    pub fn share(&self, points: &[[f64; 2]], world: &OccupancyGrid) -> Option<f64> {
        if points.is_empty() {
            return None;
        }
        let on: Vec<[f64; 2]> = points
            .iter()
            .copied()
            .filter(|p| self.contains(*p))
            .collect();
        let polluted = wall_distances(world, &on)
            .into_iter()
            .filter(|&d| d > STATIC_TOLERANCE)
            .count();
        Some(polluted as f64 / points.len() as f64)
    }

    /// The share of a 2D map's occupied cells that are pollution (see [`Self::share`]).
    pub fn grid_share(&self, map: &OccupancyGrid, world: &OccupancyGrid) -> Option<f64> {
        let occupied: Vec<[f64; 2]> = (0..map.height)
            .flat_map(|j| (0..map.width).map(move |i| (i, j)))
            .filter(|&(i, j)| map.cells[j * map.width + i] >= OCCUPIED)
            .map(|(i, j)| map.cell_center(i, j))
            .collect();
        self.share(&occupied, world)
    }

    /// The share of a 3D map's points that are pollution: those between [`FLOOR`] and
    /// [`HEAD_ROOM`] that [`Self::share`] finds against `world` (every static obstacle in that
    /// band), over all the points.
    pub fn cloud_share(&self, points: &[[f64; 3]], world: &OccupancyGrid) -> Option<f64> {
        if points.is_empty() {
            return None;
        }
        let band: Vec<[f64; 2]> = points
            .iter()
            .filter(|p| p[2] > FLOOR && p[2] <= HEAD_ROOM)
            .map(|p| [p[0], p[1]])
            .collect();
        let part = self.share(&band, world).unwrap_or(0.0);
        Some(part * band.len() as f64 / points.len() as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 m × 4 m room at 5 cm, its walls the border cells, free inside.
    fn room() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], 80, 80);
        for j in 0..80 {
            for i in 0..80 {
                g.cells[j * 80 + i] = if i == 0 || j == 0 || i == 79 || j == 79 {
                    100
                } else {
                    0
                };
            }
        }
        g
    }

    #[test]
    fn points_on_a_path_off_the_walls_are_pollution() {
        let mut paths = PeoplePaths::default();
        // Someone walked along y = 2 from x = 0.3 to x = 3.7, close to both end walls.
        for k in 0..=34 {
            paths.add_position([0.3 + 0.1 * k as f64, 2.0]);
        }
        let world = room();
        // On the path, mid-room: pollution. On the path but on the wall (x = 0.02): not. Off
        // the path (y = 3): not. 0.45 m beside the path: on it; 0.65 m: off it.
        let points = [
            [2.0, 2.0],
            [0.02, 2.0],
            [2.0, 3.0],
            [1.0, 2.45],
            [1.0, 2.65],
        ];
        let share = paths.share(&points, &world).unwrap();
        assert!((share - 2.0 / 5.0).abs() < 1e-12, "{share}");
        assert!(paths.share(&[], &world).is_none());
        // In 3D, the floor under the path and the air above heads are not pollution.
        let cloud = [
            [2.0, 2.0, 0.05],
            [2.0, 2.0, 1.0],
            [2.0, 2.0, 2.5],
            [2.0, 3.0, 1.0],
        ];
        let s3 = paths.cloud_share(&cloud, &world).unwrap();
        assert!((s3 - 0.25).abs() < 1e-12, "{s3}");
    }

    #[test]
    fn a_map_with_a_person_drawn_in_it_scores_its_cells() {
        let mut paths = PeoplePaths::default();
        paths.add_position([2.0, 2.0]);
        let world = room();
        let mut map = room();
        // The map's walls: 4 × 79 = 316 border cells; a person's two legs add 2 + 2 cells.
        for (i, j) in [(38, 40), (39, 40), (42, 40), (43, 40)] {
            map.cells[j * 80 + i] = 100;
        }
        let share = paths.grid_share(&map, &world).unwrap();
        assert!((share - 4.0 / 320.0).abs() < 1e-12, "{share}");
        assert_eq!(paths.grid_share(&world, &world), Some(0.0));
    }
}
