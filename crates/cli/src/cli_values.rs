//! Parsers for command-line values shared by several subcommands (clap `value_parser`s).

use glam::Vec3;

/// `x,y,z` as three finite numbers.
pub fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("`{s}`: {e}; expected x,y,z"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("`{s}`: expected three finite numbers x,y,z")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec3_parses_and_rejects() {
        assert_eq!(parse_vec3("1, -2,3.5"), Ok(Vec3::new(1.0, -2.0, 3.5)));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,nan").is_err());
        assert!(parse_vec3("a,b,c").is_err());
    }
}
