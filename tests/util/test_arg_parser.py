import pytest

from mimickit.util.arg_parser import COMMAND_LINE, ArgParser
from mimickit.util.errors import MimicKitError


def test_keys_values_comments_and_bools(tmp_path):
    f = tmp_path / "args.txt"
    f.write_text("# a comment line\n--num_envs 8\n--devices cpu cpu\n--visualize false\n--lr 1e-4 # trailing\n")
    p = ArgParser()
    p.load_args(["--arg_file", str(f), "--num_envs", "2", "--flag", "T"])
    assert p.parse_int("num_envs") == 2  # the command line wins over the file
    assert p.parse_strings("devices") == ["cpu", "cpu"]
    assert p.parse_bool("visualize", True) is False
    assert p.parse_bool("flag") is True
    assert p.parse_float("lr") == pytest.approx(1e-4)
    assert p.parse_string("missing", "dflt") == "dflt"


def test_empty_value_falls_back_to_default():
    p = ArgParser()
    p.load_args(["--model_file"])
    assert p.has_key("model_file")
    assert p.parse_string("model_file", "") == ""


def test_negative_numbers_are_values():
    p = ArgParser()
    p.load_args(["--offset", "-1", "-2.5"])
    assert p.parse_strings("offset") == ["-1", "-2.5"]


def test_bad_int_names_key():
    p = ArgParser()
    p.load_args(["--num_envs", "many"])
    with pytest.raises(MimicKitError, match="--num_envs"):
        p.parse_int("num_envs")


def test_missing_arg_file():
    with pytest.raises(MimicKitError, match="nope.txt"):
        ArgParser().load_args(["--arg_file", "nope.txt"])


def test_sources_name_the_command_line_or_the_file(tmp_path):
    f = tmp_path / "args.txt"
    f.write_text("--num_envs 8\n--devices cpu\n")
    p = ArgParser()
    p.load_args(["--arg_file", str(f), "--num_envs", "2"])
    assert p.source("num_envs") == COMMAND_LINE and p.source("devices") == str(f)


@pytest.mark.parametrize(
    "value, expected",
    [("1e6", 1_000_000), ("12", 12), ("-3", -3)],
)
def test_integers(value, expected):
    p = ArgParser()
    p.load_args(["--n", value])
    assert p.parse_int("n") == expected


@pytest.mark.parametrize("value", ["1.5e0", "1e400", "inf", "nan", "1.0"])
def test_non_integers_are_one_error(value):
    p = ArgParser()
    p.load_args(["--n", value])
    with pytest.raises(MimicKitError, match="--n: expected an integer"):
        p.parse_int("n")


def test_binary_arg_file_is_one_line(tmp_path):
    f = tmp_path / "args.txt"
    f.write_bytes(b"--num_envs 8\x00\x01")
    with pytest.raises(MimicKitError, match="args.txt: a binary file"):
        ArgParser().load_args(["--arg_file", str(f)])
