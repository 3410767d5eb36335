//! The `nldenoise` command: thin glue from arguments to the library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
