//! Every figure function: valid PNG (decoded with `image`, right size, not blank) and valid SVG
//! (root element, title text); bad input gives an error or a "no data" figure, never a panic.

use bostrack_core::Mask;
use bostrack_figures::{
    AxisScale, CampaignRow, ColourRange, Figure, FigureError, HistOptions, HistSeries, MapFrame,
    MapOptions, MapPoint, Quantity, RefLine, SeriesStyle, UncertaintyComponent, XyPlot, XySeries,
    ar_histogram, ar_map, campaign_figure, displacement_map, histogram, scalar_map,
    uncertainty_histogram, uncertainty_map, xy_panels, xy_plot,
};

/// Decodes the PNG, checks its size and that it is not uniform; returns the RGB image.
fn check_png(fig: &Figure) -> image::RgbImage {
    let png = fig.to_png().expect("PNG renders");
    let img = image::load_from_memory_with_format(&png, image::ImageFormat::Png)
        .expect("PNG decodes")
        .to_rgb8();
    assert_eq!(img.dimensions(), fig.size());
    let first = *img.get_pixel(0, 0);
    let differing = img.pixels().filter(|p| **p != first).count();
    let total = (img.width() * img.height()) as usize;
    assert!(
        differing > total / 100,
        "PNG nearly uniform: {differing} of {total} pixels differ from the corner"
    );
    img
}

fn check_svg(fig: &Figure, must_contain: &str) -> String {
    let svg = fig.to_svg().expect("SVG renders");
    assert!(
        svg.starts_with("<svg"),
        "no <svg root: {}",
        &svg[..svg.len().min(80)]
    );
    assert!(svg.trim_end().ends_with("</svg>"));
    assert!(svg.contains(must_contain), "SVG lacks {must_contain:?}");
    svg
}

/// A 200×150 image with dots every 10 px; the displacement is a rotation about the centre;
/// a band y in [60, 80) is outside the mask; every 17th dot is invalid.
fn synthetic() -> (Vec<MapPoint>, Mask) {
    let mask = Mask::from_fn(200, 150, |_, y| !(60..80).contains(&y));
    let mut pts = Vec::new();
    for j in 0..15 {
        for i in 0..20 {
            let (x, y) = (5.0 + 10.0 * i as f64, 5.0 + 10.0 * j as f64);
            let k = pts.len();
            let mut p = MapPoint::vector(
                x,
                y,
                0.01 * (y - 75.0),
                -0.01 * (x - 100.0),
                k % 17 != 0,
                mask.keeps(x as usize, y as usize),
            );
            p.value = 1.0 + 0.01 * x;
            pts.push(p);
        }
    }
    (pts, mask)
}

fn frame<'a>(mask: Option<&'a Mask>) -> MapFrame<'a> {
    MapFrame {
        width: 200,
        height: 150,
        title: "frame 7 (test)",
        mask,
    }
}

#[test]
fn every_map_renders_png_and_svg() {
    let (pts, mask) = synthetic();
    let f = frame(Some(&mask));
    let o = MapOptions::default();
    let figs = [
        displacement_map(&pts, &f, &o).unwrap(),
        ar_map(&pts, &f, &o).unwrap(),
        uncertainty_map(&pts, &f, UncertaintyComponent::Magnitude, &o).unwrap(),
        uncertainty_map(&pts, &f, UncertaintyComponent::X, &o).unwrap(),
        scalar_map(
            &pts,
            &f,
            &Quantity {
                name: "u_ref",
                unit: "px",
            },
            &o,
        )
        .unwrap(),
    ];
    for fig in &figs {
        assert!(fig.title().contains("frame 7 (test)"), "{}", fig.title());
        check_png(fig);
        let svg = check_svg(fig, "frame 7 (test)");
        // legend entries for the special dots
        assert!(svg.contains("outside mask"), "{}", fig.title());
        assert!(svg.contains("invalid"), "{}", fig.title());
        assert!(svg.contains("x (px)") && svg.contains("y (px, down)"));
    }
    let svg = figs[0].to_svg().unwrap();
    assert!(svg.contains("|d| (px)"), "colour bar label with unit");
    assert!(svg.contains("arrows drawn ×"), "arrow scale stated");
    // AR as the larger axis: 1 where nothing is amplified (not |AR|, which is √2 there)
    let ar = figs[1].to_svg().unwrap();
    assert!(ar.contains("max(AR_x, AR_y)") && !ar.contains("|AR|"));
    assert!(figs[2].to_svg().unwrap().contains("|u_d| (px)"));
}

#[test]
fn map_keeps_aspect_and_y_points_down() {
    // valid dots only in the top tenth of a 1000×1000 image; everything else outside the mask
    let mut pts = Vec::new();
    for j in 0..50 {
        for i in 0..50 {
            let (x, y) = (10.0 + 20.0 * i as f64, 10.0 + 20.0 * j as f64);
            pts.push(MapPoint::scalar(x, y, x, true, y < 100.0));
        }
    }
    let f = MapFrame {
        width: 1000,
        height: 1000,
        title: "orientation",
        mask: None,
    };
    let fig = scalar_map(
        &pts,
        &f,
        &Quantity {
            name: "v",
            unit: "px",
        },
        &MapOptions::default(),
    )
    .unwrap();
    let img = check_png(&fig);
    // coloured (saturated) pixels in the left 60 % of the figure (away from the colour bar)
    let saturated = |p: &image::Rgb<u8>| {
        let (mx, mn) = (p.0.iter().max().unwrap(), p.0.iter().min().unwrap());
        mx - mn > 80
    };
    // and above the legend strip (whose first marker is a viridis square)
    let xmax = img.width() * 6 / 10;
    let rows: Vec<u32> = (0..img.height() - 80)
        .filter(|&y| (0..xmax).any(|x| saturated(img.get_pixel(x, y))))
        .collect();
    assert!(!rows.is_empty());
    let (top, bottom) = (rows[0], *rows.last().unwrap());
    // the plot is about 700 px high: the coloured band must be the top ~70 px of it, i.e. near
    // the top of the figure, not the bottom
    assert!(
        bottom < img.height() / 4,
        "coloured rows {top}..{bottom} of {}",
        img.height()
    );
    assert!(bottom - top < 100, "band {top}..{bottom}");
}

#[test]
fn colour_scale_ends_are_viridis_ends() {
    // two valid dots, values 0 and 1, full range: the map must contain viridis(0) and viridis(1)
    let pts = [
        MapPoint::scalar(20.0, 20.0, 0.0, true, true),
        MapPoint::scalar(80.0, 80.0, 1.0, true, true),
    ];
    let f = MapFrame {
        width: 100,
        height: 100,
        title: "ends",
        mask: None,
    };
    let o = MapOptions {
        range: ColourRange::Full,
        ..MapOptions::default()
    };
    let img = check_png(
        &scalar_map(
            &pts,
            &f,
            &Quantity {
                name: "v",
                unit: "",
            },
            &o,
        )
        .unwrap(),
    );
    // viridis end points (matplotlib's table): #440154 and #FDE725
    let has = |c: [u8; 3]| {
        img.pixels().any(|p| {
            p.0.iter()
                .zip(c)
                .all(|(a, b)| (*a as i32 - b as i32).abs() <= 3)
        })
    };
    assert!(has([0x44, 0x01, 0x54]), "dark end missing");
    assert!(has([0xFD, 0xE7, 0x25]), "bright end missing");
}

#[test]
fn histograms_render() {
    let u_ref: Vec<f64> = (0..2000)
        .map(|k| 0.01 + 0.00001 * (k % 500) as f64)
        .collect();
    let u_grad: Vec<f64> = u_ref.iter().map(|u| 1.3 * u).collect();
    let fig = uncertainty_histogram(&u_ref, &u_grad, "frame 2").unwrap();
    check_png(&fig);
    let svg = check_svg(&fig, "frame 2");
    assert!(svg.contains("u_ref") && svg.contains("u_grad") && svg.contains("median"));
    assert!(svg.contains("(px)"));
    assert!(svg.contains("√(u_x² + u_y²)"), "the norm shown is named");

    let ar: Vec<f64> = (0..1000).map(|k| 0.8 + 0.001 * k as f64).collect();
    let fig = ar_histogram(&ar, "frame 2").unwrap();
    check_png(&fig);
    let svg = check_svg(&fig, "frame 2");
    assert!(
        svg.contains("1: no amplification") && svg.contains("max(AR_x, AR_y)"),
        "reference line at AR = 1 inside the range"
    );
}

#[test]
fn histogram_reports_values_beyond_axis_and_non_finite() {
    let v = [1.0, 2.0, 3.0, 50.0, f64::NAN];
    let fig = histogram(
        "beyond",
        &Quantity {
            name: "q",
            unit: "px",
        },
        &[HistSeries {
            label: "s",
            values: &v,
        }],
        &HistOptions {
            range: Some((0.0, 4.0)),
            bins: Some(4),
            ..HistOptions::default()
        },
    )
    .unwrap();
    let svg = check_svg(&fig, "beyond");
    assert!(svg.contains("n = 4"), "4 finite values");
    assert!(svg.contains("1 beyond axis"));
    assert!(svg.contains("1 non-finite"));
}

#[test]
fn xy_and_campaign_render() {
    let plot = XyPlot {
        title: "error against time".to_string(),
        x_label: "time per dot (µs)".to_string(),
        y_label: "RMS / CRLB".to_string(),
        x_scale: AxisScale::Log10,
        y_scale: AxisScale::Linear,
        series: vec![
            XySeries {
                label: "centroid".to_string(),
                points: vec![(0.5, 2.5), (0.9, 2.2)],
                style: SeriesStyle::LinePoints,
            },
            XySeries {
                label: "LM".to_string(),
                points: vec![(20.0, 1.0), (100.0, 1.01)],
                style: SeriesStyle::Points,
            },
        ],
        ref_lines: vec![RefLine {
            y: 1.0,
            label: "bound".to_string(),
        }],
    };
    let fig = xy_plot(&plot).unwrap();
    check_png(&fig);
    let svg = check_svg(&fig, "error against time");
    assert!(svg.contains("centroid") && svg.contains("LM") && svg.contains("bound"));
    // log axis: decade tick labels
    assert!(
        svg.contains(">\n1\n<") && svg.contains(">\n10\n<"),
        "decade ticks"
    );

    let both_log = XyPlot {
        x_scale: AxisScale::Log10,
        y_scale: AxisScale::Log10,
        ..plot.clone()
    };
    check_png(&xy_plot(&both_log).unwrap());
    let panels = xy_panels("two panels", &[plot.clone(), both_log]).unwrap();
    check_png(&panels);
    check_svg(&panels, "two panels");

    let rows: Vec<CampaignRow> = (0..20)
        .map(|k| CampaignRow {
            frame: k,
            median_d: 0.1 * k as f64,
            median_u: if k == 5 { f64::NAN } else { 0.02 },
        })
        .collect();
    let fig = campaign_figure("campaign A", &rows).unwrap();
    check_png(&fig);
    let svg = check_svg(&fig, "campaign A");
    assert!(svg.contains("median |d|") && svg.contains("median |u_d|"));
    assert!(
        svg.contains("1 point not drawable"),
        "the NaN frame is reported"
    );
}

/// The baseline (`y`) of every `<text>` element of an SVG.
fn text_baselines(svg: &str) -> Vec<f64> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            let head = &t[..t.find('>')?];
            let y = &head[head.find(" y=\"")? + 4..];
            y[..y.find('"')?].parse().ok()
        })
        .collect()
}

/// Every legend line of a map lies inside the figure, whatever the image's shape and however
/// many entries the legend has (all of them here: valid, outside the mask, invalid, masked
/// region, dots without position, and the arrow scale of a subsampled field on its own line).
#[test]
fn map_legend_lines_lie_inside_the_figure() {
    for (w, h) in [(200, 150), (60, 400), (1000, 1000), (400, 60)] {
        let mask = Mask::from_fn(w, h, |_, y| y % 40 < 30);
        let mut pts = Vec::new();
        for j in 0..h / 4 {
            for i in 0..w / 4 {
                let (x, y) = (2.0 + 4.0 * i as f64, 2.0 + 4.0 * j as f64);
                let k = pts.len();
                pts.push(MapPoint::vector(
                    x,
                    y,
                    0.3,
                    -0.2,
                    k % 7 != 0,
                    mask.keeps(x as usize, y as usize),
                ));
            }
        }
        pts.push(MapPoint::vector(f64::NAN, 1.0, 0.0, 0.0, true, true));
        let frame = MapFrame {
            width: w,
            height: h,
            title: "a frame with a long enough name to matter (frame 12 of 400)",
            mask: Some(&mask),
        };
        let fig = displacement_map(&pts, &frame, &MapOptions::default()).unwrap();
        let svg = check_svg(&fig, "px displacement");
        assert!(svg.contains("without position") && svg.contains("masked region"));
        let (_, fig_h) = fig.size();
        let lowest = text_baselines(&svg).into_iter().fold(0.0, f64::max);
        // a legend line's text reaches about half its 14 px size below its centre
        assert!(
            lowest + 8.0 <= fig_h as f64,
            "{w}×{h}: a text line at y = {lowest} in a figure {fig_h} px high"
        );
    }
}

#[test]
fn text_is_actually_drawn() {
    // the embedded font renders: the title band of the PNG holds dark pixels
    let fig = ar_histogram(&[1.0, 1.1, 1.2, 1.3], "font check").unwrap();
    let img = check_png(&fig);
    let dark = (0..img.width())
        .flat_map(|x| (0..40).map(move |y| (x, y)))
        .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 100))
        .count();
    assert!(dark > 100, "only {dark} dark pixels in the title band");
}

#[test]
fn empty_and_nan_input_give_errors_not_panics() {
    let f = frame(None);
    let o = MapOptions::default();
    assert!(matches!(
        displacement_map(&[], &f, &o),
        Err(FigureError::NoData { .. })
    ));
    let nan_pos = [MapPoint::vector(f64::NAN, 1.0, 0.1, 0.1, true, true)];
    assert!(matches!(
        displacement_map(&nan_pos, &f, &o),
        Err(FigureError::NoData { .. })
    ));
    assert!(matches!(
        uncertainty_histogram(&[], &[f64::NAN], "x"),
        Err(FigureError::NoData { .. })
    ));
    assert!(matches!(
        histogram(
            "x",
            &Quantity {
                name: "q",
                unit: ""
            },
            &[],
            &HistOptions::default()
        ),
        Err(FigureError::InvalidInput { .. })
    ));
    assert!(matches!(
        ar_histogram(&[f64::NAN; 4], "x"),
        Err(FigureError::NoData { .. })
    ));
    let nan_plot = XyPlot {
        series: vec![XySeries {
            label: "nan".to_string(),
            points: vec![(f64::NAN, 1.0), (1.0, f64::INFINITY)],
            style: SeriesStyle::Line,
        }],
        ..XyPlot::default()
    };
    assert!(matches!(
        xy_plot(&nan_plot),
        Err(FigureError::NoData { .. })
    ));
    let negative_on_log = XyPlot {
        y_scale: AxisScale::Log10,
        series: vec![XySeries {
            label: "neg".to_string(),
            points: vec![(1.0, -1.0), (2.0, 0.0)],
            style: SeriesStyle::Line,
        }],
        ..XyPlot::default()
    };
    assert!(matches!(
        xy_plot(&negative_on_log),
        Err(FigureError::NoData { .. })
    ));
    assert!(matches!(
        campaign_figure("c", &[]),
        Err(FigureError::NoData { .. })
    ));
    let all_nan_rows = [CampaignRow {
        frame: 0,
        median_d: f64::NAN,
        median_u: f64::NAN,
    }];
    assert!(campaign_figure("c", &all_nan_rows).is_err());
    assert!(xy_panels("p", &[]).is_err());
}

#[test]
fn all_invalid_map_is_a_no_data_figure() {
    // positions known but no valid value: the figure shows the dots and says so
    let pts: Vec<MapPoint> = (0..50)
        .map(|k| MapPoint::scalar(4.0 * k as f64, 75.0, f64::NAN, true, true))
        .collect();
    let fig = ar_map(&pts, &frame(None), &MapOptions::default()).unwrap();
    check_png(&fig);
    let svg = check_svg(&fig, "no valid values");
    assert!(svg.contains("invalid (n = 50)"));
}

#[test]
fn constant_values_do_not_break_the_colour_bar() {
    let pts: Vec<MapPoint> = (0..100)
        .map(|k| {
            MapPoint::scalar(
                (k % 10) as f64 * 20.0,
                (k / 10) as f64 * 15.0,
                0.5,
                true,
                true,
            )
        })
        .collect();
    let fig = uncertainty_map(
        &pts,
        &frame(None),
        UncertaintyComponent::Y,
        &MapOptions::default(),
    )
    .unwrap();
    check_png(&fig);
    check_svg(&fig, "u_d,y");
    let zeros = vec![MapPoint::vector(10.0, 10.0, 0.0, 0.0, true, true); 3];
    check_png(&displacement_map(&zeros, &frame(None), &MapOptions::default()).unwrap());
    check_png(
        &histogram(
            "flat",
            &Quantity {
                name: "q",
                unit: "",
            },
            &[HistSeries {
                label: "c",
                values: &[2.0; 10],
            }],
            &HistOptions::default(),
        )
        .unwrap(),
    );
}

#[test]
fn invalid_options_are_rejected() {
    let (pts, _) = synthetic();
    let wrong_mask = Mask::all(10, 10);
    assert!(matches!(
        displacement_map(&pts, &frame(Some(&wrong_mask)), &MapOptions::default()),
        Err(FigureError::InvalidInput { .. })
    ));
    let zero = MapFrame {
        width: 0,
        ..frame(None)
    };
    assert!(displacement_map(&pts, &zero, &MapOptions::default()).is_err());
    for o in [
        MapOptions {
            arrow_scale: Some(-1.0),
            ..MapOptions::default()
        },
        MapOptions {
            max_arrows: 0,
            ..MapOptions::default()
        },
        MapOptions {
            range: ColourRange::Percentile {
                low: 50.0,
                high: 10.0,
            },
            ..MapOptions::default()
        },
        MapOptions {
            range: ColourRange::Fixed {
                min: 1.0,
                max: f64::NAN,
            },
            ..MapOptions::default()
        },
    ] {
        assert!(matches!(
            displacement_map(&pts, &frame(None), &o),
            Err(FigureError::InvalidInput { .. })
        ));
    }
    let fig = ar_histogram(&[1.0, 2.0], "x").unwrap();
    assert!(fig.clone().with_size(100, 600).is_err());
    let small = fig.with_size(400, 300).unwrap();
    assert_eq!(check_png(&small).dimensions(), (400, 300));
}

#[test]
fn too_small_map_is_an_error_not_a_panic() {
    let (pts, _) = synthetic();
    let fig = displacement_map(&pts, &frame(None), &MapOptions::default())
        .unwrap()
        .with_size(220, 220)
        .unwrap();
    assert!(matches!(
        fig.to_png(),
        Err(FigureError::InvalidInput { .. })
    ));
    assert!(matches!(
        fig.to_svg(),
        Err(FigureError::InvalidInput { .. })
    ));
    let p = XyPlot {
        series: vec![XySeries {
            label: "s".to_string(),
            points: vec![(1.0, 1.0)],
            style: SeriesStyle::Points,
        }],
        ..XyPlot::default()
    };
    assert!(xy_panels("many", &vec![p; 9]).is_err());
}

#[test]
fn resized_map_renders() {
    let (pts, mask) = synthetic();
    let fig = displacement_map(&pts, &frame(Some(&mask)), &MapOptions::default())
        .unwrap()
        .with_size(600, 500)
        .unwrap();
    assert_eq!(check_png(&fig).dimensions(), (600, 500));
}

#[test]
fn special_characters_in_titles_are_escaped_in_svg() {
    let fig = ar_histogram(&[1.0, 2.0], "a < b & c").unwrap();
    let svg = fig.to_svg().unwrap();
    assert!(svg.contains("a &lt; b &amp; c"), "title not escaped");
}

#[test]
fn rendering_from_several_threads() {
    // the font is registered once, whichever thread comes first
    let handles: Vec<_> = (0..4)
        .map(|k| {
            std::thread::spawn(move || {
                let v: Vec<f64> = (0..100).map(|i| (i * (k + 1)) as f64).collect();
                ar_histogram(&v, &format!("thread {k}"))
                    .unwrap()
                    .to_png()
                    .unwrap()
                    .len()
            })
        })
        .collect();
    for h in handles {
        assert!(h.join().unwrap() > 1000);
    }
}
