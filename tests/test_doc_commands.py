"""Every command in the README's and docs' code blocks still reads as its program reads it."""

from check_doc_commands import ROOT, arguments, check, commands, main


def test_every_documented_command_checks(capsys):
    assert main([]) == 0, capsys.readouterr().out
    readme = commands(ROOT / "README.md")
    assert len(readme) >= 10 and any("+profile=quickstart" in c for c in readme)


def test_the_checker_catches_what_a_user_would_hit():
    for command, problem in (
        ("python roto_trl/train.py +exp=find_ppo agent.lrr=1", "ConfigCompositionException"),
        ("python roto_trl/train.py +exp=find_ppo +agent.lrr=1", "agent.lrr is not a config key"),
        ("python roto_trl/train.py resume=runs/x agent.lr=1", "resume= takes only"),
        ("python roto_trl/evaluate.py run=x weights=trained", "unknown keys ['weights']"),
        ("python roto_trl/analyse.py curves 'runs/*' --metrik x", "do not parse"),
        ("python benchmarks/train_throughput.py --fused", "--help does not list: ['--fused']"),
    ):
        assert problem in (check(*arguments(command)) or ""), command
