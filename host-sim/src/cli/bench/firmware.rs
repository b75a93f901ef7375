//! The firmware row of `gman bench`: the Cortex-M4F firmware's own instruction counts, read
//! from what it prints under QEMU (`mps2-an386`, `-icount shift=0`, `Mcu` preset, int8
//! weights in flash, `Efficient` mode). The firmware test
//! (`cargo test --release -p gman-tests --test firmware_qemu`) writes those `# ` lines to
//! [`DEFAULT_LOG`]; `gman bench --firmware-log FILE` reads another capture of the firmware's
//! output (e.g. `qemu-system-arm ... > FILE`). Nothing here is a constant: without the file
//! the row says it was not measured.

use std::path::Path;

use anyhow::{bail, Context, Result};

/// Where the firmware test writes the firmware's measurement lines.
pub const DEFAULT_LOG: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../firmware-example/target/qemu-measurements.txt"
);

/// The firmware's figures, as printed by it.
#[derive(Debug, Clone, PartialEq)]
pub struct Firmware {
    /// Mean instructions of a `step()` without an inner update.
    pub step_instr: f64,
    /// Instructions of one inner update (mean of the update steps minus the plain mean).
    pub adapt_instr: f64,
    /// The clock the firmware assumes (MHz, 1 instruction per cycle).
    pub mhz: f64,
    /// Multiply-accumulates of one step of the model the firmware ran (its `# model:
    /// macs_per_step=N` line; older captures without it: the pooled `Mcu` model's).
    pub macs: f64,
    /// Whether the firmware's blob ran int8 activations (its `# model: ... int8_activations=B`
    /// line; `None` for captures without it).
    pub int8_activations: Option<bool>,
    /// The file the figures were read from.
    pub source: String,
}

impl Firmware {
    /// The weight-storage label of the firmware's row: `int8-act` for the integer path,
    /// `int8` for int8 weights with f32 activations (or a capture that does not say).
    pub fn quant_label(&self) -> &'static str {
        if self.int8_activations == Some(true) {
            "int8-act"
        } else {
            "int8"
        }
    }
}

/// The value of `key=` in `line` (tokens separated by white space).
fn value(line: &str, key: &str) -> Option<f64> {
    line.split_whitespace()
        .find_map(|t| t.strip_prefix(key)?.strip_prefix('='))
        .and_then(|v| v.parse().ok())
}

/// Parses the firmware's output (every line; only the `# ` measurement lines are read).
pub fn parse(text: &str, source: &str) -> Result<Firmware> {
    let mut step = None;
    let mut adapt = None;
    let mut mhz = None;
    let mut macs = None;
    let mut act8 = None;
    for line in text.lines().filter_map(|l| l.trim_end().strip_prefix("# ")) {
        if line.starts_with("step without inner update:") {
            step = value(line, "mean_insns");
        } else if line.starts_with("inner update alone") {
            adapt = value(line, "update_insns");
        } else if line.starts_with("model:") {
            macs = value(line, "macs_per_step");
            act8 = value(line, "int8_activations").map(|v| v != 0.0);
        } else if let Some(rest) = line.strip_prefix("at ") {
            mhz = rest.split_whitespace().next().and_then(|v| v.parse().ok());
        }
    }
    let (Some(step_instr), Some(adapt_instr), Some(mhz)) = (step, adapt, mhz) else {
        bail!(
            "{source}: not the firmware's output (needs the `# step without inner update: \
             ... mean_insns=N`, `# inner update alone ...: update_insns=N` and `# at N MHz` lines)"
        );
    };
    if !(step_instr > 0.0 && mhz > 0.0) {
        bail!("{source}: step instructions {step_instr} or clock {mhz} MHz is not positive");
    }
    Ok(Firmware {
        step_instr,
        adapt_instr,
        mhz,
        macs: macs.unwrap_or(gman_core::Dims::MCU.macs_per_step() as f64),
        int8_activations: act8,
        source: source.to_string(),
    })
}

/// Reads the firmware's figures from `path`; `None` when the file does not exist (the
/// firmware test has not run), an error naming the file when it exists but is not readable
/// or not the firmware's output.
pub fn read(path: &Path) -> Result<Option<Firmware>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    parse(&text, &path.display().to_string()).map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

    const OUTPUT: &str = "t=0 a=1\n\
        # calibration: calib_insns=4000 calib_ticks=100 (expected 40 instructions per tick)\n\
        # step without inner update: steps=38 min_insns=10 mean_insns=1787926 max_insns=20\n\
        # step with inner update: steps=2 min_insns=10 mean_insns=110676726 max_insns=20\n\
        # inner update alone (update step - plain step): update_insns=108888800\n\
        # at 168 MHz and 1 instruction per cycle: step 10642 us, step with update 1 us, update 1 us\n\
        OK\n";

    #[test]
    fn reads_the_firmware_lines() {
        let f = parse(OUTPUT, "log").unwrap();
        assert_eq!(
            (f.step_instr, f.adapt_instr, f.mhz),
            (1_787_926.0, 108_888_800.0, 168.0)
        );
        let other = OUTPUT.replace("mean_insns=1787926", "mean_insns=5");
        assert_eq!(parse(&other, "log").unwrap().step_instr, 5.0);
        // Without a `# model:` line: the pooled Mcu model's MACs; with it: the line's.
        assert_eq!(f.macs, gman_core::Dims::MCU.macs_per_step() as f64);
        let map = format!("{OUTPUT}# model: macs_per_step=367232 map_cells=9\n");
        assert_eq!(parse(&map, "log").unwrap().macs, 367_232.0);
        // The activation mode: unknown without the key, else the line's.
        assert_eq!(f.int8_activations, None);
        assert_eq!(f.quant_label(), "int8");
        for (b, label) in [(1, "int8-act"), (0, "int8")] {
            let m =
                format!("{OUTPUT}# model: macs_per_step=367232 map_cells=9 int8_activations={b}\n");
            let g = parse(&m, "log").unwrap();
            assert_eq!(g.int8_activations, Some(b == 1));
            assert_eq!(g.quant_label(), label);
        }
    }

    #[test]
    fn refuses_other_text() {
        let e = parse("hello\n", "x.txt").unwrap_err().to_string();
        assert!(e.contains("x.txt"), "{e}");
        let no_clock = OUTPUT.replace("# at 168 MHz", "# at");
        assert!(parse(&no_clock, "log").is_err());
        assert!(read(Path::new("/nonexistent/qemu.txt")).unwrap().is_none());
    }
}
