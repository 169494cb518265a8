// A dropped folder of frames becomes one recording: the server takes one file per recording, so the folder is
// packed here into a ZIP without compression (frames are PNG/TIFF/JPEG already). The result is a Blob made of the
// original File objects between small headers, so nothing is copied into memory; the files are read once, in
// slices, for their CRC-32.

const MAX_ZIP_BYTES = 0xffffffff - 1; // plain ZIP (no ZIP64): offsets and sizes are 32-bit
const MAX_ENTRIES = 0xffff;
const SLICE_BYTES = 8 * 1024 * 1024;

let crcTable = null;
function crc32Table() {
  if (crcTable) return crcTable;
  crcTable = new Uint32Array(256);
  for (let n = 0; n < 256; n += 1) {
    let c = n;
    for (let k = 0; k < 8; k += 1) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    crcTable[n] = c >>> 0;
  }
  return crcTable;
}

/** CRC-32 (the ZIP one) of a File or Blob, read in slices. */
export async function crc32(blob) {
  const table = crc32Table();
  let crc = 0xffffffff;
  for (let start = 0; start < blob.size; start += SLICE_BYTES) {
    const bytes = new Uint8Array(await blob.slice(start, start + SLICE_BYTES).arrayBuffer());
    for (let i = 0; i < bytes.length; i += 1) crc = table[(crc ^ bytes[i]) & 0xff] ^ (crc >>> 8);
  }
  return (crc ^ 0xffffffff) >>> 0;
}

function dosDateTime(date) {
  const time = (date.getHours() << 11) | (date.getMinutes() << 5) | Math.floor(date.getSeconds() / 2);
  const day = ((date.getFullYear() - 1980) << 9) | ((date.getMonth() + 1) << 5) | date.getDate();
  return { time, day };
}

/**
 * A stored (uncompressed) ZIP of `entries` = [{ path, file }] as a Blob; `path` uses "/" and is stored as UTF-8.
 * `onProgress(doneBytes, totalBytes)` follows the CRC reading. Throws an Error naming the limit when the folder
 * is too big for a plain ZIP (then zip it with a ZIP64-capable tool and upload that file).
 */
export async function storedZip(entries, { onProgress = () => {} } = {}) {
  if (entries.length > MAX_ENTRIES) {
    throw new Error(`the folder has ${entries.length} files; at most ${MAX_ENTRIES} can be packed in the browser`);
  }
  const total = entries.reduce((sum, e) => sum + e.file.size, 0);
  if (total + entries.length * 200 > MAX_ZIP_BYTES) {
    throw new Error("the folder is over 4 GB: zip it yourself (ZIP64) and upload the .zip file");
  }
  const encoder = new TextEncoder();
  const parts = [];
  const central = [];
  let offset = 0;
  let done = 0;
  for (const { path, file } of entries) {
    const name = encoder.encode(path);
    const crc = await crc32(file);
    done += file.size;
    onProgress(done, total);
    const { time, day } = dosDateTime(new Date(file.lastModified || Date.now()));
    const local = new DataView(new ArrayBuffer(30));
    local.setUint32(0, 0x04034b50, true);
    local.setUint16(4, 20, true); // version needed
    local.setUint16(6, 0x0800, true); // UTF-8 names
    local.setUint16(8, 0, true); // stored
    local.setUint16(10, time, true);
    local.setUint16(12, day, true);
    local.setUint32(14, crc, true);
    local.setUint32(18, file.size, true);
    local.setUint32(22, file.size, true);
    local.setUint16(26, name.length, true);
    local.setUint16(28, 0, true);
    parts.push(local.buffer, name, file);
    const header = new DataView(new ArrayBuffer(46));
    header.setUint32(0, 0x02014b50, true);
    header.setUint16(4, 20, true);
    header.setUint16(6, 20, true);
    header.setUint16(8, 0x0800, true);
    header.setUint16(10, 0, true);
    header.setUint16(12, time, true);
    header.setUint16(14, day, true);
    header.setUint32(16, crc, true);
    header.setUint32(20, file.size, true);
    header.setUint32(24, file.size, true);
    header.setUint16(28, name.length, true);
    header.setUint32(42, offset, true);
    central.push(header.buffer, name);
    offset += 30 + name.length + file.size;
  }
  const centralSize = central.reduce((sum, part) => sum + part.byteLength, 0);
  const end = new DataView(new ArrayBuffer(22));
  end.setUint32(0, 0x06054b50, true);
  end.setUint16(8, entries.length, true);
  end.setUint16(10, entries.length, true);
  end.setUint32(12, centralSize, true);
  end.setUint32(16, offset, true);
  return new Blob([...parts, ...central, end.buffer], { type: "application/zip" });
}
