"""
The ``mlx-tempcomp`` command line.

User mistakes (a missing or malformed file, an unknown VERSION) print one
line starting with ``error:`` and exit with code 2, never a traceback.
"""

import argparse
import json
import sys

from .core.conversion import Output
from .core.eeprom import decode_eeprom, VOTED_FIELDS
from .core.errors import TempCompError
from .core.table import factory_table, TRIPLET_TEMPERATURES_C

EXIT_USER_ERROR = 2


class UserError(Exception):
    """A mistake in what the user asked for; reported in one line, exit code 2."""


def _read_image(path: str) -> bytes:
    try:
        with open(path, 'rb') as image_file:
            return image_file.read()
    except OSError as err:
        msg = f'cannot read EEPROM image {path}: {err.strerror}'
        raise UserError(msg) from None


def decode_eeprom_command(args: argparse.Namespace) -> int:
    output = Output(args.output)
    try:
        fields = decode_eeprom(_read_image(args.image))
        table = factory_table(fields, output, full_scale_dps=args.full_scale)
    except TempCompError as err:
        msg = f'{args.image}: {err}'
        raise UserError(msg) from None
    result = {
        'image': args.image,
        'range_code': fields.range_code,
        'full_scale_dps': fields.full_scale_dps,
        'version': fields.version,
        'has_table': table is not None,
        'tc_mv': list(fields.tc_mv),
        'ee_zro': list(fields.ee_zro),
        'ee_sf': list(fields.ee_sf),
        'outvoted_bits': dict(fields.outvoted_bits),
        'output': output.value,
    }
    if table is not None:
        result.update(tc=list(table.tc), zro=list(table.zro), sf=list(table.sf))
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f'{args.image}: VERSION {fields.version}, RANGE {fields.range_code} '
          f'(full scale {fields.full_scale_dps:g} deg/s)')
    if table is None:
        print('VERSION 0: the EEPROM holds no table; use the nominal ZRO and scale factor')
    else:
        unit = 'LSB' if output is Output.DIGITAL else 'mV'
        print(f'{output.value} output: TC in {unit} of TEMPOUT, ZRO in {unit}, '
              f'SF in {unit}/(deg/s)')
        print(f'{"triplet":<10}{"TC (mV)":>10}{"TC":>12}{"ZRO":>12}{"SF":>10}'
              f'{"EE_ZRO":>8}{"EE_SF":>7}')
        for i, temperature_c in enumerate(TRIPLET_TEMPERATURES_C):
            print(f'{f"{temperature_c:+.0f} C":<10}{fields.tc_mv[i]:>10d}{table.tc[i]:>12.3f}'
                  f'{table.zro[i]:>12.3f}{table.sf[i]:>10.4f}{fields.ee_zro[i]:>8d}'
                  f'{fields.ee_sf[i]:>7d}')
    counts = ', '.join(f'{name} {fields.outvoted_bits[name]}' for name in VOTED_FIELDS)
    print(f'out-voted bits: {counts} (total {fields.total_outvoted_bits})')
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='mlx-tempcomp',
        description='MLX90609 temperature compensation toolkit.')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
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
    decode.set_defaults(handler=decode_eeprom_command)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except UserError as err:
        print(f'error: {err}', file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == '__main__':
    sys.exit(main())
