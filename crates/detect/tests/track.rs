//! Tracking the reference seeds into gradient images with known displacement fields.

mod common;

use bostrack_core::{DotFlags, GridIndex, Seed};
use bostrack_detect::{DetectConfig, Detection, detect, track};
use bostrack_synth::{DisplacementField, FlowConfig, Scene, TruthDot};
use common::{Case, fully_inside, scene_config, score};
use std::collections::HashMap;

/// Detects the reference, tracks the gradient image of `flow`, and checks every truth dot that is
/// fully inside (in both images) and found in the reference: tracked with the reference's grid
/// index, not MISSING, centre within a quarter spacing of its true gradient position. Returns the
/// largest displacement of those dots (px) and the largest centre error.
fn check_flow(c: &Case, flow: &FlowConfig, size: usize) -> (f64, f64) {
    let mut cfg_scene = scene_config(c);
    cfg_scene.width = size;
    cfg_scene.height = size;
    cfg_scene.mask = None;
    let reference = Scene::reference(&cfg_scene).unwrap();
    let gradient = Scene::gradient(&cfg_scene, flow).unwrap();
    let cfg = DetectConfig::default();
    let det = detect(&reference.image, reference.mask.as_ref(), &cfg).unwrap();
    let sc = score(&det, &reference, 0.25 * c.spacing);
    assert_eq!(
        (sc.found, sc.spurious),
        (sc.expected, 0),
        "reference: {:?}",
        sc.problems
    );
    let tr: Detection = track(&gradient.image, gradient.mask.as_ref(), &det, &cfg).unwrap();
    assert_eq!(tr.seeds.len(), det.seeds.len());
    assert!(
        tr.seeds
            .iter()
            .zip(&det.seeds)
            .all(|(a, b)| a.index == b.index)
    );

    let (w, h) = (reference.image.width(), reference.image.height());
    let truth: HashMap<GridIndex, (&TruthDot, &TruthDot)> = reference
        .truth
        .iter()
        .zip(&gradient.truth)
        .map(|(r, g)| {
            (
                GridIndex::new(r.index.i + sc.offset.0, r.index.j + sc.offset.1),
                (r, g),
            )
        })
        .collect();
    let (mut worst_d, mut worst_e, mut checked) = (0.0f64, 0.0f64, 0);
    let tol = 0.25 * c.spacing;
    for (g, r) in tr.seeds.iter().zip(&det.seeds) {
        let Some((tr_ref, tr_grad)) = truth.get(&r.index) else {
            continue;
        };
        let inside = fully_inside(tr_ref, w, h, reference.mask.as_ref())
            && fully_inside(tr_grad, w, h, gradient.mask.as_ref());
        let found_ref = !r.flags.contains(DotFlags::MISSING);
        if tr_ref.flags.contains(DotFlags::MISSING) {
            assert!(
                g.flags.contains(DotFlags::MISSING) || !found_ref,
                "{g:?} tracked onto an empty site"
            );
            continue;
        }
        if !inside || !found_ref || tr_ref.defect.is_some() {
            continue;
        }
        checked += 1;
        let d = (tr_grad.params.x0 - tr_ref.params.x0).hypot(tr_grad.params.y0 - tr_ref.params.y0);
        worst_d = worst_d.max(d);
        assert!(
            !g.flags.contains(DotFlags::MISSING),
            "{g:?} lost (true displacement {d:.2} px)"
        );
        let e = (g.centre[0] - tr_grad.params.x0).hypot(g.centre[1] - tr_grad.params.y0);
        worst_e = worst_e.max(e);
        assert!(
            e < tol,
            "{g:?} is {e:.2} px from its dot (displacement {d:.2} px); reference seed {r:?}, truth ref ({:.2}, {:.2}) grad ({:.2}, {:.2})",
            tr_ref.params.x0,
            tr_ref.params.y0,
            tr_grad.params.x0,
            tr_grad.params.y0
        );
    }
    assert!(checked > 100, "{checked}");
    eprintln!(
        "{flow:?}: {checked} dots, largest displacement {worst_d:.2} px, largest centre error {worst_e:.3} px"
    );
    (worst_d, worst_e)
}

fn case(spacing: f64, diameter: f64, angle: f64, seed: u64) -> Case {
    Case {
        spacing,
        diameter,
        angle_deg: angle,
        noise: 0.03,
        hexagonal: false,
        mask: true,
        seed,
    }
}

/// A Gaussian bump of displacement around `centre` whose largest move, `largest` px, is at
/// `width` px from it.
fn bump(centre: [f64; 2], largest: f64, width: f64) -> FlowConfig {
    FlowConfig {
        displacement: DisplacementField::GaussianBump {
            centre,
            amplitude: largest * width / (-0.5f64).exp(),
            width,
        },
        ..Default::default()
    }
}

fn uniform(dx: f64, dy: f64) -> FlowConfig {
    FlowConfig {
        displacement: DisplacementField::Uniform { dx, dy },
        ..Default::default()
    }
}

#[test]
fn uniform_displacements_up_to_0_4_spacing_need_no_predictor() {
    for (k, (s, d, angle)) in [(8.0, 5.0, 0.0), (6.0, 2.0, 23.0), (12.0, 8.0, 61.0)]
        .into_iter()
        .enumerate()
    {
        let c = case(s, d, angle, 40 + k as u64);
        for dir in [0.0f64, 30.0, 45.0, 200.0] {
            let (sn, cs) = dir.to_radians().sin_cos();
            let m = 0.4 * s;
            let (worst, _) = check_flow(&c, &uniform(m * cs, m * sn), 256);
            assert!((worst - m).abs() < 1e-9);
        }
    }
}

/// Displacements beyond half a spacing are followed from the region of small displacement,
/// taken to be the largest connected one (a periodic target cannot tell a displacement `d` from
/// `d` minus a lattice vector); each field changes by less than 0.3 spacing between neighbours.
#[test]
fn larger_smooth_displacements_follow_the_neighbours() {
    let s = 8.0;
    let c = case(s, 5.0, 12.0, 50);
    // A BOS-like bump: |d| up to 0.8 spacing at 50 px from its centre (0.21 spacing change
    // between neighbours at most, at the centre).
    let (worst, _) = check_flow(&c, &bump([128.0, 124.0], 0.8 * s, 50.0), 256);
    assert!(worst > 0.75 * s, "{worst}");
    // A vortex turning by up to 0.7 spacing (0.23 spacing change between neighbours in its
    // core), on a larger frame so that most of it moves little.
    let core = 30.0;
    let vortex = FlowConfig {
        displacement: DisplacementField::Vortex {
            centre: [190.0, 194.0],
            strength: 0.7 * s * core / 0.638,
            core,
        },
        ..Default::default()
    };
    let (worst, _) = check_flow(&c, &vortex, 384);
    assert!(worst > 0.65 * s, "{worst}");
    // A ramp from 0 at the left edge to 0.8 spacing at the right one.
    let ramp = FlowConfig {
        displacement: DisplacementField::Affine {
            centre: [0.0, 0.0],
            offset: [0.0, 0.0],
            matrix: [[0.025, 0.0], [0.0, 0.0]],
        },
        ..Default::default()
    };
    let (worst, _) = check_flow(&c, &ramp, 256);
    assert!(worst > 0.75 * s, "{worst}");
}

/// A gradient frame's flow is local: most of the target keeps still and is taken as found
/// from the template measure at the reference centres (without a search), the dot map is
/// built around the moving region only, and growth starts from all the still dots at once.
/// Here the flow moves dots by up to 1.2 spacings (0.25 spacing change between neighbours at
/// most): the dots that moved by about one lattice vector look still too (a neighbour's dot
/// sits at their reference centre) and must still be followed through the band between. The
/// frame is large enough for the map's crop to be a third of it.
#[test]
fn a_local_flow_is_tracked_from_the_still_dots() {
    let s = 8.0;
    let c = case(s, 5.0, 7.0, 70);
    let (worst, err) = check_flow(&c, &bump([380.0, 392.0], 1.2 * s, 64.0), 768);
    assert!(worst > 1.15 * s, "{worst}");
    assert!(err < 0.5, "{err}");
}

#[test]
fn no_flow_images_keep_every_dot_in_place() {
    let c = case(8.0, 6.0, 0.0, 60);
    let cfg_scene = scene_config(&c);
    let reference = Scene::reference(&cfg_scene).unwrap();
    let det = detect(
        &reference.image,
        reference.mask.as_ref(),
        &DetectConfig::default(),
    )
    .unwrap();
    for img in bostrack_synth::stack(&cfg_scene, 3).unwrap() {
        let tr = track(
            &img,
            reference.mask.as_ref(),
            &det,
            &DetectConfig::default(),
        )
        .unwrap();
        let moved = tr
            .seeds
            .iter()
            .zip(&det.seeds)
            .filter(|(a, b): &(&Seed, &Seed)| {
                !a.flags.contains(DotFlags::MISSING) && !b.flags.contains(DotFlags::MISSING)
            })
            .map(|(a, b)| (a.centre[0] - b.centre[0]).hypot(a.centre[1] - b.centre[1]))
            .fold(0.0, f64::max);
        assert!(moved < 0.3, "a dot moved by {moved} px in a no-flow image");
        assert_eq!(tr.stats.found, det.stats.found);
    }
}

/// A tracked dot's fit window is its reference window moved by the whole pixels of its
/// displacement from the reference centre: in a no-flow image every dot keeps the reference's
/// pixels (a window centred on its own rounded centre would differ for the dots near a pixel's
/// edge), and under a uniform flow every window moves with its dot, never more than a pixel
/// from the dot's centre per axis.
#[test]
fn tracked_windows_are_the_reference_windows_moved_by_whole_pixels() {
    let c = case(8.0, 6.0, 7.0, 61);
    let cfg_scene = scene_config(&c);
    let reference = Scene::reference(&cfg_scene).unwrap();
    let cfg = DetectConfig::default();
    let det = detect(&reference.image, reference.mask.as_ref(), &cfg).unwrap();
    let half = (det.seeds[0].window.width.max(det.seeds[0].window.height) / 2) as usize;
    let side = 2 * half + 1;
    let full = |s: &Seed| s.window.width == side && s.window.height == side;
    let moved = |r: &Seed, d: [i64; 2]| {
        bostrack_core::Window::new(
            r.window.x + d[0],
            r.window.y + d[1],
            r.window.width,
            r.window.height,
        )
    };
    // no flow
    let mut own_rule_differs = 0;
    let mut checked = 0;
    for img in bostrack_synth::stack(&cfg_scene, 2).unwrap() {
        let tr = track(&img, reference.mask.as_ref(), &det, &cfg).unwrap();
        for (t, r) in tr.seeds.iter().zip(&det.seeds) {
            if !full(r) || !full(t) || t.flags.contains(DotFlags::MISSING) {
                continue;
            }
            checked += 1;
            assert_eq!(t.window, r.window, "{t:?} left the window of {r:?}");
            let own = bostrack_core::Window::centred(t.centre[0], t.centre[1], half);
            own_rule_differs += usize::from(own != r.window);
        }
    }
    assert!(checked > 500, "{checked}");
    // (the case the rule is for does occur)
    assert!(own_rule_differs > 0, "{own_rule_differs} of {checked}");
    // a uniform flow of (2.3, -1.6) px
    let gradient = Scene::gradient(&cfg_scene, &uniform(2.3, -1.6)).unwrap();
    let tr = track(&gradient.image, gradient.mask.as_ref(), &det, &cfg).unwrap();
    let (mut shifted, mut n) = (0, 0);
    for (t, r) in tr.seeds.iter().zip(&det.seeds) {
        if !full(r) || !full(t) || t.flags.contains(DotFlags::MISSING) {
            continue;
        }
        n += 1;
        let d = [
            (t.centre[0] - r.centre[0]).round() as i64,
            (t.centre[1] - r.centre[1]).round() as i64,
        ];
        assert_eq!(t.window, moved(r, d), "{t:?} from {r:?}");
        shifted += usize::from(d == [2, -2]);
        let mid = |lo: i64| (lo + half as i64) as f64;
        let off = (t.centre[0] - mid(t.window.x))
            .abs()
            .max((t.centre[1] - mid(t.window.y)).abs());
        assert!(
            off <= 1.0,
            "{t:?}: centre {off} px from its window's centre"
        );
    }
    // (nearly every dot moved by (2, -2) whole pixels: the rest lie near a pixel's edge)
    assert!(
        n > 250 && shifted as f64 > 0.8 * n as f64,
        "{shifted} of {n}"
    );
}
