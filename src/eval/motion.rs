//! Motion compared two-sided with the teacher's, on root paths and facings of the same
//! key script: each turn's frames, each stop's frames and slide, idle creep and the speed
//! under each key. A path has one root per frame: `path[0]` is the start and `actions[t]`
//! moves `path[t]` to `path[t + 1]`.

use glam::Vec3;

use crate::action::Action;
use crate::avatar::locomotion::FRAME_RATE;

/// A turn is complete when the step into a frame and the next 3 steps each move at least
/// this far horizontally (m) ...
const MIN_STEP: f32 = 1e-3;
/// ... within this many degrees of the new key's heading (the UNICA paper's measure).
const TURN_TOLERANCE_DEG: f32 = 10.0;
/// A stopped root moves slower than this (m/s) for good.
const STOPPED_SPEED: f32 = 0.05;
/// Frames of each key's run left out of its speed (a 180° turn takes the teacher 14).
const SETTLE: usize = 15;
/// Idle creep is measured over the last this many frames of an idle run ...
pub const CREEP_FRAMES: usize = 300;
/// ... that runs at least this long (the stop itself takes the teacher about 10 frames).
const CREEP_RUN: usize = CREEP_FRAMES + 30;

/// The tolerances of docs/eval (issue #48): each ratio is generated / teacher.
pub const TURN_RATIO: (f64, f64) = (0.75, 1.25);
pub const SLIDE_RATIO: (f64, f64) = (0.7, 1.3);
pub const STOP_RATIO: (f64, f64) = (0.75, 1.25);
pub const IDLE_CREEP_M: f64 = 0.02;
pub const SPEED_ERROR_PCT: f64 = 5.0;

/// A foot is planted where its lowest point is within this height (m) of its frame's
/// lowest point: the Witch teacher's stance foot stays within 4 mm of the floor through
/// her run cycle, and heel strike and toe-off pass through 1-5 cm (quick strict eval,
/// seed 48048).
pub const PLANTED_M: f32 = 0.01;
/// Foot slip against the teacher's (issue #48: within 1.5×).
pub const FOOT_SLIP_RATIO: f64 = 1.5;

/// One foot in one frame: the horizontal centre of its points and the height of its lowest
/// point above the frame's lowest point.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FootSample {
    pub centre: Vec3,
    pub lift: f32,
}

/// The sample of the foot whose points are `points[foot[..]]`; None for no foot points.
pub fn foot_sample(points: &[Vec3], foot: &[u32]) -> Option<FootSample> {
    if foot.is_empty() {
        return None;
    }
    let floor = points.iter().map(|p| p.y).fold(f32::INFINITY, f32::min);
    let lowest = foot
        .iter()
        .map(|&i| points[i as usize].y)
        .fold(f32::INFINITY, f32::min);
    let centre = foot.iter().map(|&i| points[i as usize]).sum::<Vec3>() / foot.len() as f32;
    Some(FootSample {
        centre: flat(centre),
        lift: lowest - floor,
    })
}

/// A foot's slip: (total horizontal travel in m, steps) over the steps between two
/// frames in which it is planted in both.
pub fn foot_slip(samples: &[FootSample]) -> (f64, usize) {
    samples
        .windows(2)
        .filter(|w| w[0].lift < PLANTED_M && w[1].lift < PLANTED_M)
        .fold((0.0, 0), |(total, steps), w| {
            (total + w[0].centre.distance(w[1].centre) as f64, steps + 1)
        })
}

/// Heading of a horizontal displacement in degrees: atan2(dx, dz), so W (+Z) is 0 and A
/// (+X) is 90.
pub fn heading_deg(d: Vec3) -> f32 {
    d.x.atan2(d.z).to_degrees()
}

/// `a - b` in degrees, wrapped to (-180, 180].
pub fn wrap_deg(d: f32) -> f32 {
    let r = d.rem_euclid(360.0);
    if r > 180.0 { r - 360.0 } else { r }
}

/// The heading a movement key moves toward (degrees); None for Idle.
pub fn key_heading(action: Action) -> Option<f32> {
    action.quarter().map(|q| wrap_deg(90.0 * q as f32))
}

fn flat(d: Vec3) -> Vec3 {
    Vec3::new(d.x, 0.0, d.z)
}

/// The facing (degrees, `heading_deg`'s convention) of root-centred `points` against the
/// root-centred `rest` pose facing +Z, point for point: the turn about +Y that best maps
/// the rest onto the points (least squares in the XZ plane).
pub fn facing_deg(points: &[Vec3], rest: &[Vec3]) -> f32 {
    let (mut c, mut s) = (0.0f64, 0.0f64);
    for (f, r) in points.iter().zip(rest) {
        c += (f.x * r.x + f.z * r.z) as f64;
        s += (f.x * r.z - f.z * r.x) as f64;
    }
    s.atan2(c).to_degrees() as f32
}

/// Horizontal speeds (m/s) of each step of `path`.
pub fn speeds(path: &[Vec3]) -> Vec<f32> {
    path.windows(2)
        .map(|w| flat(w[1] - w[0]).length() * FRAME_RATE)
        .collect()
}

/// The frames a key switch takes: frame `switch` is the first frame under the new key
/// (`path[switch]`, reached by `actions[switch - 1]`); the count runs up to and including
/// the first frame from which the step into it and the next 3 are on the new heading.
/// None: never within the path.
pub fn turn_frames(path: &[Vec3], switch: usize, target_deg: f32) -> Option<usize> {
    let on = |f: usize| {
        let d = flat(path[f] - path[f - 1]);
        d.length() >= MIN_STEP && wrap_deg(heading_deg(d) - target_deg).abs() <= TURN_TOLERANCE_DEG
    };
    (switch.max(1)..path.len().saturating_sub(3))
        .find(|&f| (f..f + 4).all(on))
        .map(|f| f - switch + 1)
}

/// After the keys are released at step `release` (path[release] -> path[release + 1] is
/// the first idle step) until `end` (the next key press, or the path's end): the frames
/// until the root moves slower than 0.05 m/s for good (None: never), and the slide, the
/// horizontal distance from the release to where it stopped (to `end` when it never did).
pub fn stop(path: &[Vec3], release: usize, end: usize) -> (Option<usize>, f32) {
    let v = speeds(&path[release..=end]);
    let frames = v
        .iter()
        .rposition(|&s| s >= STOPPED_SPEED)
        .map_or(0, |i| i + 1);
    let stopped = (frames < v.len()).then_some(frames);
    let at = release + stopped.unwrap_or(v.len());
    (stopped, flat(path[at] - path[release]).length())
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct TurnCompare {
    pub label: String,
    /// The first frame under the new key.
    pub frame: usize,
    pub generated: Option<usize>,
    pub teacher: Option<usize>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct StopCompare {
    pub after: Action,
    pub release: usize,
    pub frames: Option<usize>,
    pub teacher_frames: Option<usize>,
    pub slide_m: f32,
    pub teacher_slide_m: f32,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct SpeedCompare {
    pub key: Action,
    pub start: usize,
    pub speed: f32,
    pub teacher_speed: f32,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct CreepCompare {
    /// The first frame of the last `CREEP_FRAMES` of the idle run.
    pub from: usize,
    pub creep_m: f32,
    pub teacher_creep_m: f32,
}

/// The loose parts' swing after one turn or stop.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SwingCompare {
    pub label: String,
    /// The last frame under the old key.
    pub frame: usize,
    pub generated_m: f32,
    pub teacher_m: f32,
    /// Frames after the key change until the swing has died down ([`settle_frames`]).
    pub generated_settle: usize,
    pub teacher_settle: usize,
}

/// Everything compared on one script.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MotionCompare {
    pub turns: Vec<TurnCompare>,
    pub stops: Vec<StopCompare>,
    pub speeds: Vec<SpeedCompare>,
    pub creep: Vec<CreepCompare>,
    pub swings: Vec<SwingCompare>,
}

/// Frames after a key change over which the loose parts' swing is measured (the teacher's
/// stop takes about 10).
pub const SWING_FRAMES: usize = 30;
/// Swing amplitude against the teacher's (issue #48: within ±30 %).
pub const SWING_RATIO: (f64, f64) = (0.7, 1.3);

/// A swing has died down once the offset stays within this share of its largest
/// departure from where it ends ([`settle_frames`]).
pub const SETTLE_SHARE: f32 = 0.25;

/// How fast a swing decays: the frames after `offsets[0]` until the offset stays within
/// [`SETTLE_SHARE`] of its largest distance from the last offset (where the window ends);
/// 0 when it never departs more than 1 mm from there.
pub fn settle_frames(offsets: &[Vec3]) -> usize {
    let Some(&last) = offsets.last() else {
        return 0;
    };
    let away: Vec<f32> = offsets.iter().map(|o| o.distance(last)).collect();
    let largest = away.iter().copied().fold(0.0f32, f32::max);
    if largest < 1e-3 {
        return 0;
    }
    away.iter()
        .rposition(|&d| d > SETTLE_SHARE * largest)
        .map_or(0, |t| t + 1)
}

/// Where the loose parts' centre sits on the body: `centre` minus the `root`, turned by
/// minus the body's facing (degrees, `heading_deg`'s convention) about +Y.
pub fn body_offset(centre: Vec3, root: Vec3, facing_deg: f32) -> Vec3 {
    glam::Quat::from_rotation_y(-facing_deg.to_radians()) * (centre - root)
}

/// After each turn and each stop of `actions`: how far the loose parts' body offset
/// (`offsets[t]` for frame t, as paths are) moves from where it was at the key change,
/// at most, over the next [`SWING_FRAMES`] frames or until the next change; generated and
/// teacher. Empty when either side has no offsets.
pub fn swings(generated: &[Vec3], teacher: &[Vec3], actions: &[Action]) -> Vec<SwingCompare> {
    if generated.len() != actions.len() + 1 || teacher.len() != actions.len() + 1 {
        return Vec::new();
    }
    let runs = runs(actions);
    let amplitude = |offsets: &[Vec3], from: usize, to: usize| {
        offsets[from..=to]
            .iter()
            .map(|o| o.distance(offsets[from]))
            .fold(0.0f32, f32::max)
    };
    let mut out = Vec::new();
    for k in 1..runs.len() {
        let (before, (action, start, steps)) = (runs[k - 1].0, runs[k]);
        if key_heading(before).is_none() {
            continue;
        }
        let end = start + steps.min(SWING_FRAMES);
        out.push(SwingCompare {
            label: format!("{}→{}", before.letter(), action.letter()),
            frame: start,
            generated_m: amplitude(generated, start, end),
            teacher_m: amplitude(teacher, start, end),
            generated_settle: settle_frames(&generated[start..=end]),
            teacher_settle: settle_frames(&teacher[start..=end]),
        });
    }
    out
}

/// Runs of one action: (action, first step, steps).
fn runs(actions: &[Action]) -> Vec<(Action, usize, usize)> {
    let mut out: Vec<(Action, usize, usize)> = Vec::new();
    for (t, &a) in actions.iter().enumerate() {
        match out.last_mut() {
            Some((b, _, n)) if *b == a => *n += 1,
            _ => out.push((a, t, 1)),
        }
    }
    out
}

/// Compares the generated path with the teacher's on the same `actions` (both have
/// `actions.len() + 1` roots).
pub fn compare(generated: &[Vec3], teacher: &[Vec3], actions: &[Action]) -> MotionCompare {
    assert!(generated.len() == actions.len() + 1 && teacher.len() == actions.len() + 1);
    let mut out = MotionCompare::default();
    let runs = runs(actions);
    for (k, &(action, start, steps)) in runs.iter().enumerate() {
        let before = k.checked_sub(1).map(|k| runs[k].0);
        let end = start + steps;
        match (before.and_then(key_heading), key_heading(action)) {
            (Some(from), Some(to)) => {
                // actions[start] moves into path[start + 1], the first new frame.
                let label = format!(
                    "{}→{} ({:.0}°)",
                    before.map_or('?', Action::letter),
                    action.letter(),
                    wrap_deg(to - from).abs()
                );
                let within = &generated[..=end];
                out.turns.push(TurnCompare {
                    label,
                    frame: start + 1,
                    generated: turn_frames(within, start + 1, to),
                    teacher: turn_frames(&teacher[..=end], start + 1, to),
                });
            }
            (Some(_), None) => {
                let (frames, slide_m) = stop(generated, start, end);
                let (teacher_frames, teacher_slide_m) = stop(teacher, start, end);
                out.stops.push(StopCompare {
                    after: before.unwrap_or(Action::Idle),
                    release: start,
                    frames,
                    teacher_frames,
                    slide_m,
                    teacher_slide_m,
                });
            }
            _ => {}
        }
        if action == Action::Idle && steps >= CREEP_RUN {
            let from = end - CREEP_FRAMES;
            let creep = |p: &[Vec3]| flat(p[end] - p[from]).length();
            out.creep.push(CreepCompare {
                from,
                creep_m: creep(generated),
                teacher_creep_m: creep(teacher),
            });
        }
        if action != Action::Idle && steps > SETTLE + 5 {
            let mean = |p: &[Vec3]| {
                let v = speeds(&p[start + SETTLE..=end]);
                v.iter().sum::<f32>() / v.len() as f32
            };
            out.speeds.push(SpeedCompare {
                key: action,
                start,
                speed: mean(generated),
                teacher_speed: mean(teacher),
            });
        }
    }
    out
}

/// generated / teacher; infinite when the generated side never finishes; None when the
/// teacher gives nothing to compare with (it never finishes, or takes no frames).
pub fn ratio(generated: Option<f64>, teacher: Option<f64>) -> Option<f64> {
    match (generated, teacher) {
        (_, None) => None,
        (_, Some(t)) if t <= 0.0 => None,
        (None, Some(_)) => Some(f64::INFINITY),
        (Some(g), Some(t)) => Some(g / t),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_swing_settles_when_it_stays_near_where_it_ends() {
        // A damped swing about a rest 1 m along X: departures 0.4, -0.2, 0.08, -0.05, 0.
        let at = |x: f32| Vec3::X * (1.0 + x);
        let offsets = [at(0.0), at(0.4), at(-0.2), at(0.08), at(-0.05), at(0.0)];
        // Largest departure from the end 0.4; within 0.1 (a quarter) from frame 3 on.
        assert_eq!(settle_frames(&offsets), 3);
        // A swing whose decay is twice as slow settles later.
        let slow = [
            at(0.0),
            at(0.4),
            at(0.3),
            at(-0.2),
            at(-0.15),
            at(0.08),
            at(0.0),
        ];
        assert_eq!(settle_frames(&slow), 5);
        // One that never moves more than 1 mm, or nothing: 0.
        assert_eq!(settle_frames(&[at(0.0), at(0.0005), at(0.0)]), 0);
        assert_eq!(settle_frames(&[]), 0);
    }

    #[test]
    fn swings_follow_turns_and_stops_over_the_next_frames() {
        use Action::*;
        // W 10, A 40, Idle 10: a turn at step 10 and a stop at step 50 (a start at 0 is
        // not a swing). Offsets: a bump of 0.2 (teacher) and 0.1 (generated) 5 frames
        // after the turn, one of 0.3 35 frames after it (past SWING_FRAMES: not counted),
        // and 0.05 / 0.1 after the stop.
        let mut actions = vec![Forward; 10];
        actions.extend([Left; 40]);
        actions.extend([Idle; 10]);
        let bumps = |turn: f32, stop: f32| {
            let mut o = vec![Vec3::ZERO; 61];
            o[15] = Vec3::X * turn;
            o[45] = Vec3::X * 0.3;
            o[53] = Vec3::Z * stop;
            o
        };
        let s = swings(&bumps(0.1, 0.1), &bumps(0.2, 0.05), &actions);
        assert_eq!(s.len(), 2);
        assert_eq!((s[0].label.as_str(), s[0].frame), ("W→A", 10));
        assert_eq!((s[0].generated_m, s[0].teacher_m), (0.1, 0.2));
        assert_eq!((s[1].label.as_str(), s[1].frame), ("A→I", 50));
        assert_eq!((s[1].generated_m, s[1].teacher_m), (0.1, 0.05));
        // The turn's bump at frame 15 and back by 16: settled 6 frames after the change.
        assert_eq!((s[0].generated_settle, s[0].teacher_settle), (6, 6));
        assert!(swings(&[], &bumps(0.2, 0.05), &actions).is_empty());
        // Facing 90° (toward +X): a centre 1 m along +X is 1 m ahead (+Z) on the body.
        let o = body_offset(Vec3::new(3.0, 1.0, 0.0), Vec3::new(2.0, 1.0, 0.0), 90.0);
        assert!(o.distance(Vec3::Z) < 1e-6, "{o}");
    }

    #[test]
    fn foot_slip_counts_travel_between_planted_frames_only() {
        // Points: a floor point, then a two-point foot.
        let frame = |x: f32, lift: f32| {
            vec![
                Vec3::new(5.0, 0.0, 5.0),
                Vec3::new(x, lift, 1.0),
                Vec3::new(x + 0.1, lift + 0.05, 1.0),
            ]
        };
        let foot = [1, 2];
        let s = foot_sample(&frame(2.0, 0.003), &foot).unwrap();
        assert_eq!(s.centre, Vec3::new(2.05, 0.0, 1.0));
        assert!((s.lift - 0.003).abs() < 1e-6);
        assert_eq!(foot_sample(&frame(2.0, 0.0), &[]), None);
        // Planted at x = 0, 0.004, 0.010, lifted (0.1 m) while it moves 0.5 m, planted
        // again at 0.51 and 0.512: three planted steps, 0.004 + 0.006 + 0.002 m.
        let samples: Vec<FootSample> = [
            (0.0, 0.0),
            (0.004, 0.004),
            (0.010, 0.008),
            (0.26, 0.1),
            (0.51, 0.0),
            (0.512, 0.0),
        ]
        .iter()
        .map(|&(x, lift)| foot_sample(&frame(x, lift), &foot).unwrap())
        .collect();
        let (total, steps) = foot_slip(&samples);
        assert_eq!(steps, 3);
        assert!((total - 0.012).abs() < 1e-6, "{total}");
    }

    fn walk(steps: &[(Vec3, usize)]) -> Vec<Vec3> {
        let mut path = vec![Vec3::ZERO];
        for &(d, n) in steps {
            for _ in 0..n {
                let last = *path.last().unwrap();
                path.push(last + d);
            }
        }
        path
    }

    #[test]
    fn headings_follow_the_keys() {
        assert_eq!(heading_deg(Vec3::Z), 0.0);
        assert!((heading_deg(Vec3::X) - 90.0).abs() < 1e-5);
        assert_eq!(key_heading(Action::Left), Some(90.0));
        assert_eq!(key_heading(Action::Right), Some(-90.0));
        assert_eq!(key_heading(Action::Backward), Some(180.0));
        assert_eq!(wrap_deg(-190.0), 170.0);
        assert_eq!(wrap_deg(180.0), 180.0);
    }

    #[test]
    fn facing_is_the_turn_of_the_rest_pose() {
        let rest = [
            Vec3::new(0.3, 1.0, 0.1),
            Vec3::new(-0.2, 0.5, 0.4),
            Vec3::new(0.1, 0.0, -0.3),
        ];
        let turn = glam::Quat::from_rotation_y(30f32.to_radians());
        let turned: Vec<Vec3> = rest.iter().map(|&p| turn * p).collect();
        assert!((facing_deg(&turned, &rest) - 30.0).abs() < 1e-3);
        // +Z turned 30° about +Y heads 30° toward +X.
        assert!((heading_deg(turn * Vec3::Z) - 30.0).abs() < 1e-3);
    }

    #[test]
    fn a_turn_counts_the_frames_until_four_steps_are_on_the_new_heading() {
        // 5 steps +Z, 2 steps sideways-diagonal (off heading), then +X.
        let path = walk(&[
            (Vec3::Z * 0.05, 5),
            (Vec3::new(0.03, 0.0, 0.03), 2),
            (Vec3::X * 0.05, 6),
        ]);
        // Frame 6 is the first under the new key; frames 6, 7 are diagonal; 8 on heading.
        assert_eq!(turn_frames(&path, 6, 90.0), Some(3));
        assert_eq!(turn_frames(&path, 6, -90.0), None);
    }

    #[test]
    fn a_stop_gives_its_frames_and_slide() {
        // Released at step 4: 3 slowing steps of 0.02, 0.01, 0.004 m (0.6, 0.3, 0.12 m/s)
        // then 0.001 m steps (0.03 m/s).
        let mut path = walk(&[(Vec3::Z * 0.05, 4)]);
        for d in [0.02, 0.01, 0.004, 0.001, 0.001] {
            let last = *path.last().unwrap();
            path.push(last + Vec3::Z * d);
        }
        let (frames, slide) = stop(&path, 4, 9);
        assert_eq!(frames, Some(3));
        assert!((slide - 0.034).abs() < 1e-6);
        // Never stopping: the slide runs to the end.
        let path = walk(&[(Vec3::Z * 0.05, 8)]);
        let (frames, slide) = stop(&path, 4, 8);
        assert_eq!(frames, None);
        assert!((slide - 0.2).abs() < 1e-6);
    }

    #[test]
    fn compare_finds_turns_stops_speeds_and_creep() {
        use Action::*;
        let mut actions = vec![Forward; 30];
        actions.extend([Left; 30]);
        actions.extend([Idle; 340]);
        // Teacher: 0.05 m/frame forward, turns in 1 frame, stops in 1.
        let teacher = walk(&[
            (Vec3::Z * 0.05, 30),
            (Vec3::X * 0.05, 30),
            (Vec3::ZERO, 340),
        ]);
        // Generated: 10 % faster, turns in 3 frames, creeps 0.0001 m a frame while idle.
        let generated = walk(&[
            (Vec3::Z * 0.055, 30),
            (Vec3::Z * 0.055, 2),
            (Vec3::X * 0.055, 28),
            (Vec3::X * 0.0001, 340),
        ]);
        let c = compare(&generated, &teacher, &actions);
        assert_eq!(c.turns.len(), 1);
        assert_eq!(
            (c.turns[0].generated, c.turns[0].teacher),
            (Some(3), Some(1))
        );
        assert_eq!(c.turns[0].label, "W→A (90°)");
        assert_eq!(c.stops.len(), 1);
        assert_eq!(c.stops[0].teacher_frames, Some(0));
        assert_eq!(c.stops[0].frames, Some(0));
        assert_eq!(c.speeds.len(), 2);
        assert!((c.speeds[0].speed / c.speeds[0].teacher_speed - 1.1).abs() < 1e-4);
        assert_eq!(c.creep.len(), 1);
        assert!((c.creep[0].creep_m - 0.03).abs() < 1e-5);
        assert_eq!(c.creep[0].teacher_creep_m, 0.0);
        assert_eq!(ratio(Some(3.0), Some(1.0)), Some(3.0));
        assert_eq!(ratio(None, Some(2.0)), Some(f64::INFINITY));
        assert_eq!(ratio(Some(2.0), Some(0.0)), None);
    }
}
