/** The package's version (package.json's; a test keeps the two equal), sent in the user agent. */
export const VERSION = "0.1.0";
export const USER_AGENT = `sdfclient-ts/${VERSION}`;
