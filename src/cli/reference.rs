//! The CLI reference page, `docs/reference/cli-help.md`: every command's `--help`, made from
//! the clap definitions, so the book cannot drift from the binary (a test compares them;
//! `JETPILOT_BLESS=1` rewrites the page).

use clap::CommandFactory;

/// The page's text: one section per command, depth first, each with its long help at a
/// fixed width of 100 columns.
pub fn markdown() -> String {
    let mut out = String::from(
        "# Command reference\n\n\
         Generated from the binary's clap definitions (a build with `--features train`, as the\n\
         test suite builds it; without it the `train il`, `train ddpg`, ... commands are\n\
         absent). A test keeps it in step: after changing a command, run\n\
         `JETPILOT_BLESS=1 scripts/test.sh -E 'test(/cli_reference/)'`. The overview with\n\
         examples: [Commands](cli.md).\n",
    );
    let mut root = super::Cli::command().term_width(100).max_term_width(100);
    root.build();
    section(&mut out, &mut root, "jetpilot");
    out
}

fn section(out: &mut String, cmd: &mut clap::Command, path: &str) {
    let help = cmd.render_long_help().to_string();
    out.push_str(&format!("\n## `{path}`\n\n```text\n"));
    for line in help.trim_end().lines() {
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out.push_str("```\n");
    let mut subs: Vec<clap::Command> = cmd
        .get_subcommands()
        .filter(|s| s.get_name() != "help")
        .cloned()
        .collect();
    for sub in &mut subs {
        let name = format!("{path} {}", sub.get_name());
        section(out, sub, &name);
    }
}

#[cfg(all(test, feature = "train"))]
mod tests {
    #[test]
    fn cli_reference_page_is_the_help_the_binary_prints() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/reference/cli-help.md");
        let want = super::markdown();
        if std::env::var_os("JETPILOT_BLESS").is_some() {
            std::fs::write(&path, &want).unwrap();
        }
        let have = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            have == want,
            "{} is out of date: run JETPILOT_BLESS=1 scripts/test.sh -E 'test(/cli_reference/)' and commit it",
            path.display()
        );
    }
}
