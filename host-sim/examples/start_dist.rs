//! Prints the distribution of shortest-path lengths (actions to a goal-visible state) of the
//! official val episodes' starts and of sampled training starts.
use gman_host_sim::sim::{Split, World};
use rand::SeedableRng;
fn hist(name: &str, v: &mut [u32]) {
    v.sort();
    let q = |p: f64| v[((v.len() - 1) as f64 * p) as usize];
    let zero = v.iter().filter(|&&d| d == 0).count();
    println!(
        "{name}: n={} zero={:.1}% p10={} p25={} median={} p75={} p90={}",
        v.len(),
        100.0 * zero as f64 / v.len() as f64,
        q(0.1),
        q(0.25),
        q(0.5),
        q(0.75),
        q(0.9)
    );
}
fn main() -> anyhow::Result<()> {
    let world = match std::env::args().nth(1) {
        Some(d) => World::load(std::path::Path::new(&d))?,
        None => World::synthetic(2022),
    };
    let eps = world.episodes(Split::Val, None)?;
    let mut v: Vec<u32> = eps
        .iter()
        .map(|e| {
            let sc = &world.scenes[e.scene];
            let st = sc.state_index(e.start).unwrap();
            world.goal_table(e.scene, e.target).dist[st] as u32
        })
        .collect();
    hist("val", &mut v);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut t: Vec<u32> = (0..4000)
        .map(|_| {
            let e = world.sample_train_episode(&mut rng);
            let sc = &world.scenes[e.scene];
            let st = sc.state_index(e.start).unwrap();
            world.goal_table(e.scene, e.target).dist[st] as u32
        })
        .collect();
    hist("train", &mut t);
    Ok(())
}
