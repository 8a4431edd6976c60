//! The auto-rigger on the shared Witch: her own rig as a skeleton tree, its tokens, and
//! the reduction they buy over the naive bone-by-bone encoding.

mod common;

use common::witch;

use unica::autorig::skeleton::{Class, UnitCube, of_character};
use unica::autorig::tokens::{decode, encode, naive_length, quantise, quantised};
use unica::avatar::load_character;

#[test]
fn the_witch_rig_round_trips_through_tokens() {
    let character = load_character(&witch()).unwrap();
    let skeleton = of_character(&character);
    assert_eq!(skeleton.class, Class::Humanoid);
    // 20 body + 38 hand joints; Root, Body and the IK pole targets carry no weight.
    assert_eq!(skeleton.len(), 58, "{:?}", skeleton.names);
    let cube = UnitCube::of_points(&character.rest_mesh().positions);
    let unit = skeleton.map_joints(|p| cube.to_unit(p));
    let tokens = encode(&unit).unwrap();
    let decoded = decode(&tokens).unwrap();
    let expected = quantised(&unit);
    // Template joints come back in the template's order: compare them by name.
    let parent_name =
        |s: &unica::autorig::skeleton::Skeleton, j: usize| s.parents[j].map(|p| s.names[p].clone());
    assert_eq!(decoded.len(), expected.len());
    for (j, name) in expected.names.iter().enumerate() {
        let k = decoded.names.iter().position(|n| n == name).unwrap();
        assert_eq!(decoded.joints[k], expected.joints[j], "{name}");
        assert_eq!(
            parent_name(&decoded, k),
            parent_name(&expected, j),
            "{name}"
        );
    }
    // The IK rig's feet hang from the root in the file; the template hangs them from
    // the lower legs.
    let foot = decoded.names.iter().position(|n| n == "Foot.L").unwrap();
    assert_eq!(decoded.names[decoded.parents[foot].unwrap()], "LowerLeg.L");
    // Hips sit near the middle of the cube, feet near its bottom.
    assert!(quantise(unit.joints[0].y) > 100);
    let foot = unit.names.iter().position(|n| n == "Foot.L").unwrap();
    assert!(unit.joints[foot].y < -0.8, "{}", unit.joints[foot]);
    assert_eq!(tokens.len(), 3 + 2 + 3 * 58);
    let reduction = 1.0 - tokens.len() as f32 / naive_length(&unit) as f32;
    // Without the template the same tree is all chains and branches.
    let mut free = unit.clone();
    free.class = Class::Other;
    let chains = encode(&free).unwrap();
    let chain_reduction = 1.0 - chains.len() as f32 / naive_length(&unit) as f32;
    println!(
        "Witch: naive {} tokens; chains {} ({:.1} % fewer); template {} ({:.1} % fewer)",
        naive_length(&unit),
        chains.len(),
        100.0 * chain_reduction,
        tokens.len(),
        100.0 * reduction,
    );
    assert!(chain_reduction > 0.2 && reduction > chain_reduction);
    let round = decode(&chains).unwrap();
    assert_eq!(round.len(), unit.len());
}
