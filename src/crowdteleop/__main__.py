from crowdteleop.cli import app

app(prog_name="crowdteleop")
