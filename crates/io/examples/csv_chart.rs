//! Draws columns of a CSV file (first line may be a `#` comment, then a header) as a PNG line
//! chart: `csv_chart IN.csv OUT.png TITLE XCOL YCOL[:ERRCOL] [YCOL[:ERRCOL] ...]`.
//! Used for docs figures, e.g. docs/data/temperature_vs_dt.csv.

use hemodpd_io::plot::{line_chart, Series};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 6 {
        return Err("usage: csv_chart IN.csv OUT.png TITLE XCOL YCOL[:ERRCOL] ...".into());
    }
    let text = std::fs::read_to_string(&args[1])?;
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().ok_or("empty file")?.split(',').map(str::trim).collect();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap_or(f64::NAN)).collect())
        .collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or(format!("no column {name}"))
    };
    let x = col(&args[4])?;
    let mut series = Vec::new();
    for spec in &args[5..] {
        let (y, e) = spec
            .split_once(':')
            .map_or((spec.as_str(), None), |(a, b)| (a, Some(b)));
        let yi = col(y)?;
        let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r[x], r[yi])).collect();
        series.push(match e {
            Some(e) => {
                let ei = col(e)?;
                Series::error_bars(y, pts, rows.iter().map(|r| r[ei]).collect())
            }
            None => Series::line_with_points(y, pts),
        });
    }
    line_chart(&args[2], &args[3], &args[4], "value", &series)?;
    Ok(())
}
