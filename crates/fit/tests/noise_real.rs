//! Issue #14, item 10: the single-image noise model on the real sample, against the no-flow
//! stack (skipped with a message when the data are missing; fails when CI=true).
//!
//! Measured (variance in counts² at the background, 60 counts, and at the dot peaks, 1000 and
//! 1600 counts; the stack's binned variance in brackets):
//!
//! | estimate | 60 | 1000 | 1600 |
//! |---|---|---|---|
//! | stack, 10 images (`noise_from_stack`), before | 232 (209) | 1154 (1062) | 1742 (1399) |
//! | reference, whole image, before (read 0, gain 0.435) | 26 | 435 | 696 |
//! | reference, whole image (`locate`), now | 262 | 1071 | 1587 |
//! | reference, with the mask | 413 | 1041 | 1443 |
//! | `im_0001` (one stack frame), with the mask | 682 | 2510 | 3677 |
//!
//! (The stack's own model leaves the floor-clipped samples out now too: 234, 1152, 1737.) The
//! dark band (about 10 % of the pixels at 0, clipped at the floor) made the whole-image read
//! variance 0; floor-clipped samples are now left out, and `locate`'s whole-image model is
//! within 20 % of the stack's variance at the background and at the peaks (+12 %, −7 %, −9 %).
//! That agreement is partly owed to the dimmer pixels next to the dark band, whose static
//! variance is smaller: with the mask the estimate is within 20 % at the peaks but 1.8 times
//! the stack's at the background, and on a stack frame it is about twice the stack's at every
//! level. The reason, measured on the stack: the
//! 4th-difference residual of the (averaged, nearly noise-free) reference and of the mean of
//! the stack holds a static pixel-to-pixel variance S (about 240 counts² at the background,
//! 850 at the peaks: fixed-pattern noise or the print's texture, white like noise, so no
//! high-pass filter separates it), and a single frame's residual is S plus the temporal
//! variance T. A single image cannot tell S from T: its model is an upper bound of the temporal
//! noise. That is documented (crates/fit/README.md); the pipeline uses the stack whenever one is
//! configured, and `locate --read-noise` takes a known model.

mod common;

use bostrack_fit::{estimate_noise_detailed, noise_from_stack};

#[test]
fn single_image_noise_on_the_real_sample() {
    let Some((img, mask, stack)) = common::real_sample() else {
        return;
    };
    let ns = noise_from_stack(&stack, Some(&mask)).unwrap();
    let whole = estimate_noise_detailed(&img, None).unwrap();
    let masked = estimate_noise_detailed(&img, Some(&mask)).unwrap();
    let frame = estimate_noise_detailed(&stack[0], Some(&mask)).unwrap();
    let levels = [60.0, 1000.0, 1600.0];
    for (name, f) in [("whole", &whole), ("masked", &masked), ("frame", &frame)] {
        let row: Vec<String> = levels
            .iter()
            .map(|&m| {
                format!(
                    "{m}: {:.0} (stack {:.0})",
                    f.model.variance(m),
                    ns.variance(m)
                )
            })
            .collect();
        println!(
            "{name}: {:?} ± ({:.1}, {:.4}), resolved {}: {}",
            f.model,
            f.read_variance_se,
            f.gain_se,
            f.resolved,
            row.join(", ")
        );
    }
    // `locate` on the whole reference: the dark band no longer sets the read noise to 0, and
    // the model is within 20 % of the stack's variance at the background and at the dot peaks
    assert!(
        whole.resolved && whole.model.read_variance > 100.0,
        "{whole:?}"
    );
    for m in levels {
        let r = whole.model.variance(m) / ns.variance(m);
        assert!((r - 1.0).abs() < 0.2, "{m}: whole reference / stack {r}");
    }
    // the reported uncertainty is a real one: positive, finite, well below the values
    for f in [&whole, &masked, &frame] {
        assert!(f.read_variance_se > 0.0 && f.read_variance_se < 0.3 * f.model.read_variance);
        assert!(f.gain_se > 0.0 && f.gain_se < 0.3 * f.model.gain);
    }
    // with the mask: at the dot peaks within 20 % of the stack
    for m in [1000.0, 1600.0] {
        let r = masked.model.variance(m) / ns.variance(m);
        assert!((r - 1.0).abs() < 0.2, "{m}: reference / stack {r}");
    }
    // the single image's static pixel-to-pixel variance: an upper bound of the temporal noise,
    // about twice it on a single frame (documented, not resolved by a single image)
    for m in levels {
        let r = frame.model.variance(m) / ns.variance(m);
        assert!((1.5..3.0).contains(&r), "{m}: frame / stack {r}");
        assert!(masked.model.variance(m) > 0.8 * ns.variance(m));
    }
}
