//! The report's figures: CSV series and the SVG charts drawn from them.

use super::*;

/// A named series of (x, y) points for a plot.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub dashed: bool,
}

impl Series {
    /// The series of `ys` against `xs`, pairwise (as many points as the shorter of the two).
    pub(super) fn of(
        name: impl Into<String>,
        xs: &[f64],
        ys: impl IntoIterator<Item = f64>,
        dashed: bool,
    ) -> Self {
        Series {
            name: name.into(),
            points: xs.iter().copied().zip(ys).collect(),
            dashed,
        }
    }
}

/// The numbers behind a figure: named columns, as the experiments hold them (one vector per
/// quantity), written as one CSV with a row per index.
#[derive(Default)]
pub(super) struct Columns {
    header: Vec<String>,
    columns: Vec<Vec<f64>>,
}

impl Columns {
    /// Columns that start with `name` (usually the x axis).
    pub(super) fn starting_with(
        name: impl Into<String>,
        values: impl IntoIterator<Item = f64>,
    ) -> Self {
        let mut columns = Columns::default();
        columns.push(name, values);
        columns
    }

    pub(super) fn push(&mut self, name: impl Into<String>, values: impl IntoIterator<Item = f64>) {
        self.header.push(name.into());
        self.columns.push(values.into_iter().collect());
    }

    /// One row per index: the transpose of the columns, as many rows as the shortest column
    /// has values (the experiments give every column one value per depth).
    pub(super) fn rows(&self) -> Vec<Vec<f64>> {
        let len = self.columns.iter().map(Vec::len).min().unwrap_or(0);
        (0..len)
            .map(|i| self.columns.iter().map(|c| c[i]).collect())
            .collect()
    }

    /// Writes the columns as a CSV at `path` (header row, then [`Columns::rows`]).
    pub(super) fn write_csv(&self, path: &Path) -> Result<(), ReportError> {
        csv(path, &self.header, &self.rows())
    }
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// Draws an SVG line chart (no system fonts: plotters' built-in text metrics).
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<(), ReportError> {
    let plot_err = |e: String| ReportError::Plot {
        path: path.to_owned(),
        message: e,
    };
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| ReportError::Io {
            path: dir.to_owned(),
            source,
        })?;
    }
    let finite = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|(x, y)| x.is_finite() && y.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in finite {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if (x1 - x0).abs() < 1e-12 {
        x1 = x0 + 1.0;
    }
    let pad = 0.05 * (y1 - y0).abs().max(1e-9);
    let (y0, y1) = (y0.min(0.0) - pad, y1 + pad);
    let root = SVGBackend::new(path, (820, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| plot_err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| plot_err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .draw()
        .map_err(|e| plot_err(e.to_string()))?;
    for (i, s) in series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect();
        let style = ShapeStyle::from(&color).stroke_width(2);
        if s.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts.clone(), 6, 4, style))
                .map_err(|e| plot_err(e.to_string()))?
                .label(s.name.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
        } else {
            chart
                .draw_series(LineSeries::new(pts.clone(), style))
                .map_err(|e| plot_err(e.to_string()))?
                .label(s.name.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
        }
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
            .map_err(|e| plot_err(e.to_string()))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(|e| plot_err(e.to_string()))?;
    root.present().map_err(|e| plot_err(e.to_string()))?;
    Ok(())
}

pub(super) fn csv(path: &Path, header: &[String], rows: &[Vec<f64>]) -> Result<(), ReportError> {
    let mut text = header.join(",");
    text.push('\n');
    for row in rows {
        let cells: Vec<String> = row.iter().map(|v| format!("{v:.6e}")).collect();
        text.push_str(&cells.join(","));
        text.push('\n');
    }
    write(path, &text)
}

/// Draws an SVG scatter chart, one point per series, x on a log10 scale.
pub(super) fn scatter_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    points: &[(String, f64, f64)],
) -> Result<(), ReportError> {
    let plot_err = |e: String| ReportError::Plot {
        path: path.to_owned(),
        message: e,
    };
    let pts: Vec<(String, f64, f64)> = points
        .iter()
        .filter(|(_, x, y)| x.is_finite() && *x > 0.0 && y.is_finite())
        .map(|(n, x, y)| (n.clone(), x.log10(), *y))
        .collect();
    let (mut x0, mut x1, mut y1) = (f64::MAX, f64::MIN, 1.0_f64);
    for (_, x, y) in &pts {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y1 = y1.max(*y);
    }
    if x0 > x1 {
        (x0, x1) = (0.0, 1.0);
    }
    let root = SVGBackend::new(path, (900, 620)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| plot_err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((x0 - 0.3)..(x1 + 0.3), 0.0..(1.1 * y1))
        .map_err(|e| plot_err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .draw()
        .map_err(|e| plot_err(e.to_string()))?;
    chart
        .draw_series(LineSeries::new(
            vec![(x0 - 0.3, 7.0), (x1 + 0.3, 7.0)],
            ShapeStyle::from(&BLACK).stroke_width(1),
        ))
        .map_err(|e| plot_err(e.to_string()))?
        .label("7% (JND)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
    for (i, (name, x, y)) in pts.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let marker = i / PALETTE.len();
        let point = (*x, *y);
        let drawn = if marker.is_multiple_of(2) {
            chart
                .draw_series(std::iter::once(Circle::new(point, 5, color.filled())))
                .map_err(|e| plot_err(e.to_string()))?
        } else {
            chart
                .draw_series(std::iter::once(TriangleMarker::new(
                    point,
                    6,
                    color.filled(),
                )))
                .map_err(|e| plot_err(e.to_string()))?
        };
        drawn
            .label(name.clone())
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| plot_err(e.to_string()))?;
    root.present().map_err(|e| plot_err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn columns_are_written_one_row_per_index() {
        let dir = tempfile::tempdir().unwrap();
        let mut columns = Columns::starting_with("depth_mm", [1.0, 2.0, 3.0]);
        columns.push("force_n", vec![0.5, 1.25, 2.0]);
        columns.push("short", [7.0, 8.0]);
        assert_eq!(
            columns.rows(),
            vec![vec![1.0, 0.5, 7.0], vec![2.0, 1.25, 8.0]]
        );
        let path = dir.path().join("figure.csv");
        columns.write_csv(&path).unwrap();
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "depth_mm,force_n,short\n1.000000e0,5.000000e-1,7.000000e0\n2.000000e0,1.250000e0,8.000000e0\n"
        );
    }

    #[test]
    fn a_plot_names_its_series_and_skips_points_that_are_not_finite() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nested/plot.svg");
        let series = [
            Series::of(
                "FEM neo-Hookean",
                &[1.0, 2.0, 3.0],
                [0.1, f64::NAN, 0.4],
                false,
            ),
            Series::of("Hertz", &[1.0, 3.0], [0.2, 0.5], true),
        ];
        line_plot(
            &path,
            "Force against depth",
            "depth (mm)",
            "force (N)",
            &series,
        )
        .unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..svg.len().min(80)]);
        for text in [
            "FEM neo-Hookean",
            "Hertz",
            "Force against depth",
            "depth (mm)",
        ] {
            assert!(svg.contains(text), "{text} missing from the plot");
        }
        assert!(!svg.contains("NaN"));
    }
}
