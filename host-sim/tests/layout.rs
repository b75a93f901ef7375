//! The object layout of the real floor plans: `rule` (seeded placement) and `thor5` (AI2-THOR
//! 5.0 positions and boxes).

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use gman_host_sim::sim::data::{fingerprint, fingerprint_for, THOR5_DIR};
use gman_host_sim::sim::offline::OfflineOptions;
use gman_host_sim::sim::scene::thor5_category_name;
use gman_host_sim::sim::world::auto_layout;
use gman_host_sim::sim::{ObjectLayout, Split, World, DEFAULT_WORLD_SEED};

/// FNV-1a over bytes.
fn fnv(h: &mut u64, bytes: &[u8]) {
    for &b in bytes {
        *h ^= b as u64;
        *h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
}

/// Hash of every scene's instances: name, ids, category and position bits.
fn objects_hash(w: &World) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for s in &w.scenes {
        fnv(&mut h, s.name.as_bytes());
        for o in &s.objects {
            for id in &o.ids {
                fnv(&mut h, id.as_bytes());
            }
            fnv(&mut h, &o.category.to_le_bytes());
            for v in o.pos {
                fnv(&mut h, &v.to_bits().to_le_bytes());
            }
            fnv(&mut h, &[o.known as u8]);
        }
    }
    h
}

/// Hash of the observation tables of some scenes: visible instances and in-view weights.
fn tables_hash(w: &World, names: &[&str]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for n in names {
        let id = w.scene_id(n).expect("scene");
        let t = w.tables(id);
        for (s, o) in t.obs.iter().enumerate() {
            for &i in &t.visible_instances[s] {
                fnv(&mut h, &i.to_le_bytes());
            }
            for v in &o.in_view {
                fnv(&mut h, &v.instance.to_le_bytes());
                fnv(&mut h, &v.weight.to_bits().to_le_bytes());
            }
            for f in &o.features {
                fnv(&mut h, &f.to_bits().to_le_bytes());
            }
        }
    }
    h
}

/// Recorded before the object layouts existed (the code of the seeded rule alone), on the
/// shared data: every scene's instances, and the observation tables of four scenes.
const RULE_OBJECTS_HASH: u64 = 0x84f8_688b_d936_abc0;
const RULE_TABLES_HASH: u64 = 0x9fd1_eabb_e1c6_aeb2;
const TABLE_SCENES: [&str; 4] = ["FloorPlan22", "FloorPlan228", "FloorPlan1", "FloorPlan430"];

fn load(dir: &Path, layout: ObjectLayout) -> anyhow::Result<World> {
    World::load_with_layout(dir, DEFAULT_WORLD_SEED, &OfflineOptions::default(), layout)
}

fn world(layout: ObjectLayout) -> Option<&'static World> {
    static RULE: OnceLock<Option<World>> = OnceLock::new();
    static THOR5: OnceLock<Option<World>> = OnceLock::new();
    let cell = match layout {
        ObjectLayout::Rule => &RULE,
        ObjectLayout::Thor5 => &THOR5,
    };
    cell.get_or_init(|| common::data_dir().map(|d| load(&d, layout).expect("load real world")))
        .as_ref()
}

/// A private copy of the data directory (small: a few MB), to break.
fn copy_data(name: &str) -> Option<PathBuf> {
    let src = common::data_dir()?;
    let dst = std::env::temp_dir().join(format!("gman-layout-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dst);
    fn copy(a: &Path, b: &Path) {
        if a.is_dir() {
            std::fs::create_dir_all(b).unwrap();
            for e in std::fs::read_dir(a).unwrap() {
                let e = e.unwrap();
                copy(&e.path(), &b.join(e.file_name()));
            }
        } else {
            std::fs::copy(a, b).unwrap();
        }
    }
    copy(&src, &dst);
    Some(dst)
}

#[test]
fn rule_layout_is_the_seeded_rule_bit_for_bit() {
    let Some(w) = world(ObjectLayout::Rule) else {
        return;
    };
    assert_eq!(w.layout, ObjectLayout::Rule);
    assert_eq!(objects_hash(w), RULE_OBJECTS_HASH);
    assert_eq!(tables_hash(w, &TABLE_SCENES), RULE_TABLES_HASH);
    assert!(w
        .scenes
        .iter()
        .all(|s| s.objects.iter().all(|o| o.aabb.is_none() && !o.thor5)));
}

#[test]
fn auto_chooses_thor5_when_the_sidecar_exists() {
    let Some(d) = common::data_dir() else { return };
    assert_eq!(auto_layout(&d), ObjectLayout::Thor5);
    assert_eq!(World::load(&d).unwrap().layout, ObjectLayout::Thor5);
    let Some(c) = copy_data("auto") else { return };
    std::fs::remove_dir_all(c.join(THOR5_DIR)).unwrap();
    assert_eq!(auto_layout(&c), ObjectLayout::Rule);
    let w = World::load(&c).unwrap();
    assert_eq!(w.layout, ObjectLayout::Rule);
    assert_eq!(objects_hash(&w), RULE_OBJECTS_HASH);
    let e = format!("{:#}", load(&c, ObjectLayout::Thor5).unwrap_err());
    assert!(
        e.contains("objects_thor5") && e.contains("does not exist"),
        "{e}"
    );
    std::fs::remove_dir_all(&c).unwrap();
}

/// The sidecar's objects of the 40 categories per scene: (category name, id) -> position.
fn sidecar(dir: &Path, scene: &str) -> HashMap<(String, String), [f32; 3]> {
    let text = std::fs::read_to_string(dir.join(THOR5_DIR).join(format!("{scene}.json"))).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["objects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| {
            let f = |k: &str| o[k].as_f64().unwrap() as f32;
            (
                (
                    thor5_category_name(o["type"].as_str().unwrap()).to_string(),
                    o["id"].as_str().unwrap().to_string(),
                ),
                [f("x"), f("y"), f("z")],
            )
        })
        .collect()
}

#[test]
fn thor5_instances_come_from_the_sidecar_and_2x_positions_stay() {
    let (Some(d), Some(t5), Some(rule)) = (
        common::data_dir(),
        world(ObjectLayout::Thor5),
        world(ObjectLayout::Rule),
    ) else {
        return;
    };
    let (mut from_file, mut fallback, mut matched, mut known) = (0, 0, 0, 0);
    for (s, r) in t5.scenes.iter().zip(&rule.scenes) {
        assert_eq!(s.name, r.name);
        assert_eq!(s.present, r.present, "{}: present categories", s.name);
        let file = sidecar(&d, &s.name);
        let rule_pos: HashMap<&str, [f32; 3]> = r
            .objects
            .iter()
            .filter(|o| o.known)
            .flat_map(|o| o.ids.iter().map(move |i| (i.as_str(), o.pos)))
            .collect();
        let mut ids: Vec<&str> = s
            .objects
            .iter()
            .flat_map(|o| o.ids.iter().map(|i| i.as_str()))
            .collect();
        ids.sort_unstable();
        let n = ids.len();
        ids.dedup();
        assert_eq!(ids.len(), n, "{}: an id names two instances", s.name);
        let ids: std::collections::HashSet<&str> = ids.into_iter().collect();
        for o in &s.objects {
            let name = t5.category_name(o.category).to_string();
            if s.split == Split::Train {
                assert!(
                    !t5.categories[o.category as usize].unseen,
                    "{}: unseen {name}",
                    s.name
                );
            }
            if o.thor5 {
                from_file += 1;
                let p = file
                    .get(&(name.clone(), o.ids[0].clone()))
                    .unwrap_or_else(|| panic!("{}: {} not in the sidecar", s.name, o.ids[0]));
                assert_eq!(*p, o.pos, "{}: {}", s.name, o.ids[0]);
                assert!(o.aabb.is_some());
                // A category with a 5.0 instance has no 2.x instance in the scene.
                assert!(!s
                    .objects
                    .iter()
                    .any(|x| x.category == o.category && !x.thor5));
            } else if o.known {
                known += 1;
                matched += o.aabb.is_some() as usize;
                assert_eq!(
                    Some(&o.pos),
                    rule_pos.get(o.ids[0].as_str()),
                    "{}: {}",
                    s.name,
                    o.ids[0]
                );
            } else {
                // Placed by the rule: only for a category left without an instance (the
                // sidecar lacks it, or its 5.0 objects are 2.x instances of another type).
                assert!(s.rule_fallback.contains(&o.category), "{}: {name}", s.name);
                assert!(
                    file.keys()
                        .all(|(c, id)| *c != name || ids.contains(id.as_str())),
                    "{}: {name} is in the file",
                    s.name
                );
            }
        }
        fallback += s.rule_fallback.len();
        assert_eq!(matched_in(s), s.thor5_matched);
    }
    println!(
        "thor5: {from_file} instances from the sidecar, {known} 2.x instances ({matched} with a 5.0 box), {fallback} (scene, category) pairs placed by the rule"
    );
    assert!(from_file > 500 && matched > known / 2);
    // FloorPlan430 lists a BathtubBasin that AI2-THOR 5.0 does not have (it has a Bathtub).
    let s = &t5.scenes[t5.scene_id("FloorPlan430").unwrap()];
    assert!(s
        .rule_fallback
        .contains(&t5.category_id("BathtubBasin").unwrap()));
}

fn matched_in(s: &gman_host_sim::sim::scene::Scene) -> usize {
    s.objects
        .iter()
        .filter(|o| o.known && !o.thor5 && o.aabb.is_some())
        .count()
}

#[test]
fn boxes_make_big_objects_visible_from_further() {
    let (Some(t5), Some(rule)) = (world(ObjectLayout::Thor5), world(ObjectLayout::Rule)) else {
        return;
    };
    // Share of states where a Fridge is visible, over the val kitchens.
    let fridge = t5.category_id("Fridge").unwrap();
    let share = |w: &World| {
        let (mut v, mut n) = (0usize, 0usize);
        for &s in w.split_scenes(Split::Val).unwrap() {
            if w.scenes[s].room != gman_host_sim::sim::RoomType::Kitchen {
                continue;
            }
            let t = w.tables(s);
            v += t.obs.iter().filter(|o| o.is_visible(fridge)).count();
            n += t.obs.len();
        }
        v as f64 / n as f64
    };
    let (a, b) = (share(t5), share(rule));
    println!(
        "Fridge visible in {:.2}% of val kitchen states (thor5), {:.2}% (rule)",
        100.0 * a,
        100.0 * b
    );
    assert!(a > b, "thor5 {a} rule {b}");
}

#[test]
fn fingerprint_covers_the_sidecar_only_under_thor5() {
    let Some(c) = copy_data("fp") else { return };
    let rule0 = fingerprint(&c).unwrap();
    assert_eq!(fingerprint_for(&c, ObjectLayout::Rule).unwrap(), rule0);
    let t0 = fingerprint_for(&c, ObjectLayout::Thor5).unwrap();
    assert_ne!(t0, rule0);
    let f = c.join(THOR5_DIR).join("FloorPlan22.json");
    let text = std::fs::read_to_string(&f).unwrap();
    std::fs::write(&f, text.replacen("\"x\":", "\"x\": ", 1)).unwrap();
    assert_eq!(fingerprint(&c).unwrap(), rule0);
    assert_ne!(fingerprint_for(&c, ObjectLayout::Thor5).unwrap(), t0);
    std::fs::remove_dir_all(&c).unwrap();
}

#[test]
fn bad_sidecar_files_are_refused_naming_file_and_key() {
    let Some(c) = copy_data("bad") else { return };
    let f = c.join(THOR5_DIR).join("FloorPlan22.json");
    let good = std::fs::read_to_string(&f).unwrap();
    let err = |text: &str| {
        std::fs::write(&f, text).unwrap();
        format!("{:#}", load(&c, ObjectLayout::Thor5).unwrap_err())
    };
    // A missing key.
    let e = err(&good.replacen("\"aabb_size\"", "\"aabb_sizes\"", 1));
    assert!(
        e.contains("FloorPlan22.json") && e.contains("aabb_size"),
        "{e}"
    );
    // A negative box size.
    let v: serde_json::Value = serde_json::from_str(&good).unwrap();
    let mut bad = v.clone();
    bad["objects"][0]["aabb_size"][1] = serde_json::json!(-1.0);
    let e = err(&bad.to_string());
    assert!(
        e.contains("FloorPlan22.json") && e.contains("aabb_size[1]"),
        "{e}"
    );
    // A coordinate out of range.
    let mut bad = v.clone();
    bad["objects"][2]["z"] = serde_json::json!(1e9);
    let e = err(&bad.to_string());
    assert!(e.contains("FloorPlan22.json") && e.contains("key z"), "{e}");
    // Another scene's file under this name.
    let mut bad = v.clone();
    bad["scene"] = serde_json::json!("FloorPlan24");
    let e = err(&bad.to_string());
    assert!(
        e.contains("FloorPlan22.json") && e.contains("key scene"),
        "{e}"
    );
    // Not JSON.
    let e = err("{");
    assert!(
        e.contains("FloorPlan22.json") && e.contains("malformed"),
        "{e}"
    );
    // A missing file while the directory exists.
    std::fs::remove_file(&f).unwrap();
    let e = format!("{:#}", load(&c, ObjectLayout::Thor5).unwrap_err());
    assert!(
        e.contains("FloorPlan22.json") && e.contains("missing"),
        "{e}"
    );
    // The rule layout does not read the sidecar at all.
    assert_eq!(
        objects_hash(&load(&c, ObjectLayout::Rule).unwrap()),
        RULE_OBJECTS_HASH
    );
    std::fs::remove_dir_all(&c).unwrap();
}
