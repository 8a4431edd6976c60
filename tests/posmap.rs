//! Position maps of the Witch: the rest pose gathered lands exactly on its pixels, the
//! foreground share and the surface coverage of the six views are measured and reported.

use std::path::Path;

use unica::avatar::description::Description;
use unica::avatar::load_character;
use unica::avatar::reference::Reference;
use unica::avatar::teacher::Teacher;
use unica::posmap::table::VIEWS;
use unica::posmap::{MAP_SIZE, SurfaceTable};

fn witch_teacher() -> Teacher {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/witch/source/Witch.gltf");
    let character = load_character(&path).unwrap();
    let description = Description::find(&character, None).unwrap();
    Teacher::new(character, description).unwrap()
}

#[test]
fn the_rest_pose_gathered_lands_on_its_pixel_centres() {
    let teacher = witch_teacher();
    let reference = Reference::new(&teacher).unwrap();
    let mesh = teacher.character.rest_mesh();
    let points = reference.gather(&mesh.positions, &mesh.indices);
    let mut worst: f32 = 0.0;
    for (&pixel, p) in reference.table.pixels.iter().zip(&points) {
        let v = SurfaceTable::view_of(pixel);
        let (view, projection) = (&VIEWS[v], &reference.table.projections[v]);
        let q = projection.project(view, *p);
        let (row, col) = (
            pixel as usize / MAP_SIZE - view.row,
            pixel as usize % MAP_SIZE - view.col,
        );
        worst = worst
            .max((q.x - (col as f32 + 0.5)).abs())
            .max((q.y - (row as f32 + 0.5)).abs());
    }
    // 1e-5 of the avatar's ~2 m is 2e-5 m; at ~50 px per metre that is 1e-3 px.
    assert!(
        worst < 1e-3,
        "a gathered point is {worst} px from its pixel centre"
    );
}

#[test]
fn the_witch_map_covers_most_of_the_surface() {
    let teacher = witch_teacher();
    let reference = Reference::new(&teacher).unwrap();
    let report = reference.report(&teacher);
    eprintln!("{}", serde_json::to_string_pretty(&report).unwrap());
    assert!(
        (0.15..0.45).contains(&report.foreground_share),
        "{}",
        report.foreground_share
    );
    assert!(
        report.view_pixels.iter().all(|(_, n)| *n > 100),
        "{:?}",
        report.view_pixels
    );
    // Measured 0.85: the Witch's layered hair (a quarter of the surface area, 59 % seen)
    // and the face under the brim hide from every outside view. The design aims at 0.97
    // (docs/architecture.md, Position maps).
    assert!(
        report.surface_seen > 0.8,
        "surface seen {}",
        report.surface_seen
    );
    // Face and hands (issue #17), measured 2026-11-24: face 81 pixels against an even
    // share by area of 107, hands 112 against 156. Each region is found (its bones are
    // the humanoid's) and gets pixels, at least half its even share.
    for region in &report.regions {
        assert!(
            region.pixels > 0 && region.pixels as f32 > 0.5 * region.fair_pixels,
            "{region:?}"
        );
        assert!(
            region.area_share > 0.005 && region.area_share < 0.2,
            "{region:?}"
        );
    }
    let names: Vec<&str> = report.regions.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["face", "hands"]);
    assert!(!reference.waist.is_empty());
    // The root from the waist pixels (the belt's surface) is near the waist bones' mean.
    let mesh = teacher.character.rest_mesh();
    let points = reference.gather(&mesh.positions, &mesh.indices);
    let root = unica::posmap::GroupNorm::root(&points, &reference.waist);
    assert!(
        root.distance(teacher.root()) < 0.25,
        "pixel root {root} vs bone root {}",
        teacher.root()
    );
}
