//! One module per subcommand: its arguments and its logic.

pub mod serve;
