pub fn run(_a: QualityArgs) -> anyhow::Result<()> { todo!() }
#[derive(clap::Args, Debug)] pub struct QualityArgs {}
