"""
The ``mlx-tempcomp decode-eeprom`` command: the factory table of an MLX90609 EEPROM image.

Prints the decoded fields and the table (or JSON with ``--json``) and warns,
per voted field, when its three copies disagree; ``--strict`` refuses such
an image with exit code 2.
"""

import argparse
import json
import sys

from .errors import UserError
from ..core.errors import TempCompError
from ..core.mlx90609 import (decode_eeprom, factory_table, Output, TRIPLET_TEMPERATURES_C,
                             VOTED_FIELDS)


def add_parser(commands) -> None:
    """Add the ``decode-eeprom`` subcommand."""
    decode = commands.add_parser(
        'decode-eeprom', help='decode a 128-byte MLX90609 EEPROM image',
        description='Decode the factory table of a 128-byte MLX90609 EEPROM image '
                    '(Melexis AN2 sections 3.1-3.4) and count out-voted bits.')
    decode.add_argument('image', help='binary file of 128 bytes, address 0 first')
    decode.add_argument('--output', choices=[o.value for o in Output],
                        default=Output.DIGITAL.value,
                        help='express the table for the digital (LSB) or analog (mV) output')
    decode.add_argument('--full-scale', type=float, metavar='DPS',
                        help='full scale in deg/s, overriding 5 x RANGE')
    decode.add_argument('--json', action='store_true', help='print JSON')
    decode.add_argument('--strict', action='store_true',
                        help='exit with code 2 when any voted field has out-voted bits (the '
                             'warnings name them)')
    decode.set_defaults(handler=decode_eeprom_command)


def _read_image(path: str) -> bytes:
    try:
        with open(path, 'rb') as image_file:
            return image_file.read()
    except OSError as err:
        msg = f'cannot read EEPROM image {path}: {err.strerror}'
        raise UserError(msg) from None


_VOTED_VALUES = {'RANGE': lambda fields: fields.range_code,
                 'VERSION': lambda fields: fields.version,
                 **{f'TC{i}': (lambda fields, i=i: fields.tc_mv[i]) for i in range(3)}}


def _outvoted_warnings(fields) -> list:
    """One line per voted field whose copies disagree: the copies and what won."""
    lines = []
    for name in VOTED_FIELDS:
        bits = fields.outvoted_bits[name]
        if bits:
            copies = ', '.join(str(value) for value in fields.voted_copies[name])
            won = _VOTED_VALUES[name](fields)
            lines.append(f'warning: {name}: {bits} bit{"s" if bits > 1 else ""} out-voted; '
                         f'copies {copies}; the majority {won} was used (wrong if two copies '
                         'of a bit went bad)')
    return lines


def _result(image: str, fields, table, output: Output) -> dict:
    """Give the fields, the table and the vote counts as ``--json`` prints them."""
    result = {
        'image': image,
        'range_code': fields.range_code,
        'full_scale_dps': fields.full_scale_dps,
        'version': fields.version,
        'has_table': table is not None,
        'tc_mv': list(fields.tc_mv),
        'ee_zro': list(fields.ee_zro),
        'ee_sf': list(fields.ee_sf),
        'outvoted_bits': dict(fields.outvoted_bits),
        'voted_copies': {name: list(copies) for name, copies in fields.voted_copies.items()},
        'output': output.value,
    }
    if table is not None:
        result.update(tc=list(table.tc), zro=list(table.zro), sf=list(table.sf))
    return result


def _print_table(fields, table, output: Output) -> None:
    if table is None:
        print('VERSION 0: the EEPROM holds no table; use the nominal ZRO and scale factor')
        return
    unit = 'LSB' if output is Output.DIGITAL else 'mV'
    print(f'{output.value} output: TC in {unit} of TEMPOUT, ZRO in {unit}, '
          f'SF in {unit}/(deg/s)')
    print(f'{"triplet":<10}{"TC (mV)":>10}{"TC":>12}{"ZRO":>12}{"SF":>10}'
          f'{"EE_ZRO":>8}{"EE_SF":>7}')
    for i, temperature_c in enumerate(TRIPLET_TEMPERATURES_C):
        print(f'{f"{temperature_c:+.0f} C":<10}{fields.tc_mv[i]:>10d}{table.tc[i]:>12.3f}'
              f'{table.zro[i]:>12.3f}{table.sf[i]:>10.4f}{fields.ee_zro[i]:>8d}'
              f'{fields.ee_sf[i]:>7d}')


def decode_eeprom_command(args: argparse.Namespace) -> int:
    output = Output(args.output)
    try:
        fields = decode_eeprom(_read_image(args.image))
        table = factory_table(fields, output, full_scale_dps=args.full_scale)
    except TempCompError as err:
        msg = f'{args.image}: {err}'
        raise UserError(msg) from None
    warnings = _outvoted_warnings(fields)
    for line in warnings:
        print(f'{args.image}: {line}', file=sys.stderr)
    if warnings and args.strict:
        names = ', '.join(name for name in VOTED_FIELDS if fields.outvoted_bits[name])
        msg = f'{args.image}: out-voted bits in {names}; --strict refuses the image'
        raise UserError(msg)
    if args.json:
        print(json.dumps(_result(args.image, fields, table, output), indent=2))
        return 0
    print(f'{args.image}: VERSION {fields.version}, RANGE {fields.range_code} '
          f'(full scale {fields.full_scale_dps:g} deg/s)')
    _print_table(fields, table, output)
    counts = ', '.join(f'{name} {fields.outvoted_bits[name]}' for name in VOTED_FIELDS)
    print(f'out-voted bits: {counts} (total {fields.total_outvoted_bits})')
    return 0
