"""The one ``NAME=VALUE`` parser of the command line (``--param``, ``--condition``, ``--fix``)."""

import pytest
import typer

from bayesdoor.cli._common import parse_assignments


def test_values_come_back_per_name_as_lists():
    assert parse_assignments(["K = 1863", "c=0.5"], "--param") == {"K": [1863.0], "c": [0.5]}
    assert parse_assignments(["v=0.3,0.4"], "--condition", ["v"], several=True) == {"v": [0.3, 0.4]}
    assert parse_assignments([], "--fix", ["K"]) == {}


@pytest.mark.parametrize(
    ("items", "options", "message"),
    [
        (["K"], {}, "error: --param takes NAME=VALUE, got 'K'"),
        (["=3"], {}, "error: --param takes NAME=VALUE, got '=3'"),
        (["K"], {"known": ["K", "c"]}, "error: --param takes NAME=VALUE (e.g. --param K=...)"),
        (["v"], {"several": True}, "error: --param takes NAME=VALUE[,VALUE...], got 'v'"),
        (["K=1", "K=2"], {}, "error: --param K is given twice: give each name once"),
        (
            ["k=1"],
            {"known": ["K", "c"]},
            "error: --param k: unknown name; the known names are K, c",
        ),
        (["K=stiff"], {}, "error: --param K: 'stiff' is not a number"),
        (["K=1,2"], {}, "error: --param K: '1,2' is not a number"),
        (["v=1,x"], {"several": True}, "'1,x' is not a number or a list of numbers"),
    ],
)
def test_each_mistake_exits_with_one_line_naming_it(capsys, items, options, message):
    with pytest.raises(typer.Exit) as exit_:
        parse_assignments(items, "--param", **options)
    assert exit_.value.exit_code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
